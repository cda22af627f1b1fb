//! Wavefront OBJ with MTL material libraries.
//!
//! `tobj` parses the geometry (polygons kept whole, separate position / texture / normal
//! indices); a first pass over the text here checks every statement `tobj` would reject or
//! misread, so errors carry line numbers, and strips what `tobj` would misread (`l` lines with
//! three or more points, vertex colours present on only some `v` lines). MTL files are parsed
//! here, leniently: a missing or unreadable library or texture is a warning, never a failure.

use super::polygon::triangulate;
use super::texture::{self, Wrap};
use super::{MeshAsset, MeshError, MeshInstance, MeshMaterial, TriangleMesh, unit};
use crate::scene::material::MaterialParams;
use glam::{Affine3A, Vec2, Vec3};
use std::cell::RefCell;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Loads an OBJ file whose bytes are `bytes`.
pub(super) fn load(file: &Path, bytes: &[u8]) -> Result<MeshAsset, MeshError> {
    let err = |line: Option<usize>, message: String| MeshError::Obj {
        file: file.to_path_buf(),
        line,
        message,
    };
    if bytes.starts_with(&[0xFE, 0xFF]) || bytes.starts_with(&[0xFF, 0xFE]) {
        return Err(err(
            Some(1),
            "the file is UTF-16 text; OBJ files must be ASCII or UTF-8".into(),
        ));
    }
    let bytes = bytes.strip_prefix(&[0xEF, 0xBB, 0xBF]).unwrap_or(bytes);
    let scan = prescan(bytes).map_err(|(line, m)| err(Some(line), m))?;
    if scan.v == 0 && scan.faces == 0 {
        return Err(err(
            None,
            "no vertices and no faces (not an OBJ file?)".into(),
        ));
    }
    let text: std::borrow::Cow<[u8]> = if scan.needs_rewrite() {
        std::borrow::Cow::Owned(rewrite(bytes, scan.mixed_colors))
    } else {
        std::borrow::Cow::Borrowed(bytes)
    };

    let base = file.parent().unwrap_or(Path::new(".")).to_path_buf();
    let libs = RefCell::new(Libraries::default());
    let options = tobj::LoadOptions {
        single_index: false,
        triangulate: false,
        ignore_points: true,
        ignore_lines: true,
    };
    let mut reader: &[u8] = &text;
    let (models, _) = tobj::load_obj_buf(&mut reader, &options, |mtl: &Path| {
        libs.borrow_mut().load(&base, mtl)
    })
    .map_err(|e| err(None, tobj_message(e)))?;
    let libs = libs.into_inner();

    let mut asset = MeshAsset::empty();
    asset.warnings.extend(libs.warnings);
    let stem = file
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();

    let mut textures: HashMap<PathBuf, Option<usize>> = HashMap::new();
    for m in &libs.materials {
        let base_color_texture = match &m.map_kd {
            None => None,
            Some((path, wrap, place)) => match textures.get(path) {
                Some(&slot) => slot,
                None => {
                    let slot = match load_texture(path, *wrap) {
                        Ok(t) => {
                            asset.textures.push(t);
                            Some(asset.textures.len() - 1)
                        }
                        Err(e) => {
                            asset.warnings.push(format!(
                                "{place}: texture {}: {e}; material {} drawn without it",
                                path.display(),
                                m.name
                            ));
                            None
                        }
                    };
                    textures.insert(path.clone(), slot);
                    slot
                }
            },
        };
        asset.materials.push(MeshMaterial {
            name: m.name.clone(),
            params: m.params,
            base_color_texture,
        });
    }
    let known: std::collections::HashSet<&str> =
        libs.materials.iter().map(|m| m.name.as_str()).collect();
    for (name, line) in &scan.usemtl {
        if !known.contains(name.as_str()) {
            asset.warnings.push(format!(
                "{}:{line}: usemtl {name}: no such material in the loaded libraries; the \
                 default material is used",
                file.display()
            ));
        }
    }
    if scan.lines > 0 || scan.points > 0 {
        asset.warnings.push(format!(
            "{}: {} line and {} point elements skipped (only faces are drawn)",
            file.display(),
            scan.lines,
            scan.points
        ));
    }
    for line in &scan.empty_usemtl {
        asset.warnings.push(format!(
            "{}:{line}: `usemtl` without a name; the default material is used",
            file.display()
        ));
    }
    if scan.not_utf8.0 > 0 {
        asset.warnings.push(format!(
            "{}:{}: {} lines are not UTF-8; read with replacement characters",
            file.display(),
            scan.not_utf8.1,
            scan.not_utf8.0
        ));
    }
    if scan.small_faces > 0 {
        asset.warnings.push(format!(
            "{}: {} faces with fewer than 3 vertices skipped",
            file.display(),
            scan.small_faces
        ));
    }
    if let Some(line) = scan.mixed_colors {
        asset.warnings.push(format!(
            "{}:{line}: vertex colours on only some `v` lines; all vertex colours ignored",
            file.display()
        ));
    }

    let n_materials = libs.materials.len();
    let mut by_name: HashMap<String, usize> = HashMap::new();
    for model in &models {
        let name = if model.name.is_empty() || model.name == "unnamed_object" {
            stem.clone()
        } else {
            model.name.clone()
        };
        let slot = *by_name.entry(name.clone()).or_insert_with(|| {
            asset.meshes.push(TriangleMesh {
                name,
                ..TriangleMesh::default()
            });
            asset.meshes.len() - 1
        });
        let material = match model.mesh.material_id {
            Some(id) if id < n_materials => id as u32 + 1,
            _ => 0,
        };
        append_model(&mut asset.meshes[slot], &model.mesh, material)
            .map_err(|m| err(None, format!("{}: {m}", model.name)))?;
    }
    asset.meshes.retain(|m| !m.triangles.is_empty());
    if asset.meshes.is_empty() {
        asset
            .warnings
            .push(format!("{}: no faces: nothing to draw", file.display()));
    }
    for (i, m) in asset.meshes.iter().enumerate() {
        asset.instances.push(MeshInstance {
            mesh: i,
            transform: Affine3A::IDENTITY,
            name: m.name.clone(),
        });
    }
    Ok(asset)
}

/// What the first pass found.
#[derive(Default)]
struct Scan {
    v: usize,
    faces: usize,
    lines: usize,
    points: usize,
    small_faces: usize,
    /// A line where a `v` statement's colours differ in presence from an earlier one.
    mixed_colors: Option<usize>,
    usemtl: Vec<(String, usize)>,
    /// `l` statements with three or more points, which `tobj` would read as faces.
    long_lines: bool,
    /// `usemtl` or `mtllib` statements not written as `keyword name` from the line's start,
    /// which `tobj` would misread.
    odd_statements: bool,
    /// Lines of `usemtl` statements without a name.
    empty_usemtl: Vec<usize>,
    /// How many lines are not UTF-8 (read with replacement characters), and the first.
    not_utf8: (usize, usize),
}

impl Scan {
    fn needs_rewrite(&self) -> bool {
        self.long_lines || self.mixed_colors.is_some() || self.odd_statements || self.not_utf8.0 > 0
    }
}

/// What `usemtl` without a name is rewritten to: a name no library defines, so `tobj` gives
/// the following faces no material (the default one).
const NO_MATERIAL: &str = "\u{1}hytrace: no material";

/// Checks every statement `tobj` reads; the error is (line, message).
fn prescan(bytes: &[u8]) -> Result<Scan, (usize, String)> {
    let mut s = Scan::default();
    let (mut vt, mut vn) = (0usize, 0usize);
    let mut with_color: Option<bool> = None;
    // Largest positive index per kind, with its line, checked against the totals at the end
    // (tobj resolves positive indices when a group ends).
    let mut max_ref = [(0usize, 0usize); 3];
    let mut seen_usemtl = std::collections::HashSet::new();
    for (i, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let ln = i + 1;
        if raw.contains(&0) {
            return Err((
                ln,
                "contains NUL bytes: a binary file, not OBJ text".to_string(),
            ));
        }
        let line = String::from_utf8_lossy(raw);
        if let std::borrow::Cow::Owned(_) = line {
            if s.not_utf8.0 == 0 {
                s.not_utf8.1 = ln;
            }
            s.not_utf8.0 += 1;
        }
        let line: &str = &line;
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        // tobj reads the first `n` numbers of `vt` and `vn` and ignores the rest.
        let floats = |words: std::str::SplitWhitespace, n: usize, what: &str| {
            let v: Vec<&str> = words.take(n).collect();
            if v.len() < n {
                return Err((ln, format!("`{key}` needs {n} numbers ({what})")));
            }
            for w in &v {
                w.parse::<f32>()
                    .map_err(|_| (ln, format!("`{key}`: cannot read {w:?} as a number")))?;
            }
            Ok(())
        };
        match key {
            "v" => {
                let words: Vec<&str> = words.collect();
                if words.len() < 3 {
                    return Err((ln, "`v` needs 3 coordinates".into()));
                }
                let mut xyz = [0f32; 3];
                for (k, w) in words[..3].iter().enumerate() {
                    xyz[k] = w
                        .parse()
                        .map_err(|_| (ln, format!("`v`: cannot read {w:?} as a number")))?;
                }
                let mut colored = false;
                match words.len() {
                    3 => {}
                    4 => {
                        let w: f32 = words[3]
                            .parse()
                            .map_err(|_| (ln, format!("`v`: cannot read w = {:?}", words[3])))?;
                        if w == 0.0 {
                            return Err((ln, "`v`: w is 0".into()));
                        }
                        xyz = xyz.map(|c| c / w);
                    }
                    6 => {
                        for w in &words[3..] {
                            w.parse::<f32>().map_err(|_| {
                                (ln, format!("`v`: cannot read colour {w:?} as a number"))
                            })?;
                        }
                        colored = true;
                    }
                    n => {
                        return Err((
                            ln,
                            format!("`v` has {n} numbers; expected x y z, x y z w or x y z r g b"),
                        ));
                    }
                }
                if !xyz.iter().all(|c| c.is_finite()) {
                    return Err((ln, format!("`v` {xyz:?} is not finite")));
                }
                match with_color {
                    None => with_color = Some(colored),
                    Some(c) if c != colored && s.mixed_colors.is_none() => {
                        s.mixed_colors = Some(ln)
                    }
                    _ => {}
                }
                s.v += 1;
            }
            "vt" => {
                floats(words, 2, "u v")?;
                vt += 1;
            }
            "vn" => {
                floats(words, 3, "x y z")?;
                vn += 1;
            }
            "f" | "l" => {
                let counts = [s.v, vt, vn];
                let mut corners = 0;
                for token in words {
                    corners += 1;
                    let parts: Vec<&str> = token.split('/').collect();
                    if parts.len() > 3 {
                        return Err((ln, format!("`{key}`: bad vertex {token:?}")));
                    }
                    if parts[0].is_empty() {
                        return Err((
                            ln,
                            format!("`{key}`: vertex {token:?} has no position index"),
                        ));
                    }
                    for (kind, part) in parts.iter().enumerate() {
                        if part.is_empty() {
                            continue;
                        }
                        let x: isize = part.parse().map_err(|_| {
                            (
                                ln,
                                format!("`{key}`: cannot read index {part:?} in {token:?}"),
                            )
                        })?;
                        let what = ["position", "texture coordinate", "normal"][kind];
                        if x == 0 {
                            return Err((
                                ln,
                                format!("`{key}`: {what} index 0 (indices start at 1)"),
                            ));
                        }
                        if x < 0 {
                            if x.unsigned_abs() > counts[kind] {
                                return Err((
                                    ln,
                                    format!(
                                        "`{key}`: relative {what} index {x} reaches before the \
                                         first one ({} so far)",
                                        counts[kind]
                                    ),
                                ));
                            }
                        } else if x as usize > max_ref[kind].0 {
                            max_ref[kind] = (x as usize, ln);
                        }
                    }
                }
                if key == "l" {
                    s.lines += 1;
                    if corners >= 3 {
                        s.long_lines = true;
                    }
                } else if corners < 3 {
                    s.small_faces += 1;
                } else {
                    s.faces += 1;
                }
            }
            "p" => s.points += 1,
            "usemtl" | "mtllib" => {
                let name = line.trim_start()[key.len()..].trim();
                if name.is_empty() && key == "usemtl" {
                    s.empty_usemtl.push(ln);
                    s.odd_statements = true;
                    continue;
                }
                if line.trim_end() != format!("{key} {name}") {
                    s.odd_statements = true;
                }
                if key == "usemtl" && seen_usemtl.insert(name.to_string()) {
                    s.usemtl.push((name.to_string(), ln));
                }
            }
            _ => {}
        }
    }
    for (kind, (total, what)) in [
        (s.v, "positions"),
        (vt, "texture coordinates"),
        (vn, "normals"),
    ]
    .into_iter()
    .enumerate()
    {
        let (max, ln) = max_ref[kind];
        // tobj ignores texture and normal indices when the file has none of them.
        let ignored = kind > 0 && total == 0;
        if max > total && !ignored {
            return Err((
                ln,
                format!("index {max} is out of range: the file has {total} {what}"),
            ));
        }
    }
    Ok(s)
}

/// The text with `l` statements blanked, `usemtl` and `mtllib` statements written plainly
/// and, when `colors` is set, vertex colours removed.
fn rewrite(bytes: &[u8], colors: Option<usize>) -> Vec<u8> {
    let mut out = Vec::with_capacity(bytes.len());
    for raw in bytes.split(|&b| b == b'\n') {
        let line = String::from_utf8_lossy(raw);
        let mut words = line.split_whitespace();
        match words.next() {
            Some("l") => {}
            Some(key @ ("usemtl" | "mtllib")) => {
                let mut name = line.trim_start()[key.len()..].trim();
                if name.is_empty() && key == "usemtl" {
                    name = NO_MATERIAL;
                }
                out.extend_from_slice(format!("{key} {name}").as_bytes());
            }
            Some("v") if colors.is_some() => {
                let w: Vec<&str> = words.collect();
                if w.len() == 6 {
                    out.extend_from_slice(format!("v {} {} {}", w[0], w[1], w[2]).as_bytes());
                } else {
                    out.extend_from_slice(line.as_bytes());
                }
            }
            _ => out.extend_from_slice(line.as_bytes()),
        }
        out.push(b'\n');
    }
    out
}

fn tobj_message(e: tobj::LoadError) -> String {
    use tobj::LoadError as E;
    match e {
        E::FaceVertexOutOfBounds => {
            "a face refers to a vertex defined later, after its group ends".into()
        }
        E::FaceTexCoordOutOfBounds => {
            "a face refers to a texture coordinate defined after its group ends".into()
        }
        E::FaceNormalOutOfBounds => "a face refers to a normal defined after its group ends".into(),
        other => other.to_string(),
    }
}

/// Appends a `tobj` model's faces (triangulated) to `out`, all with `material`.
fn append_model(out: &mut TriangleMesh, m: &tobj::Mesh, material: u32) -> Result<(), String> {
    let np = m.positions.len() / 3;
    let positions: Vec<Vec3> = (0..np)
        .map(|i| {
            Vec3::new(
                m.positions[3 * i],
                m.positions[3 * i + 1],
                m.positions[3 * i + 2],
            )
        })
        .collect();
    let corners = m.indices.len();
    let has_uv = !m.texcoords.is_empty() && m.texcoord_indices.len() == corners;
    let has_n = !m.normals.is_empty() && m.normal_indices.len() == corners;
    let position_of = |c: usize| -> Result<usize, String> {
        let p = m.indices[c] as usize;
        if p < np {
            Ok(p)
        } else {
            Err(format!("position index {p} out of range ({np})"))
        }
    };

    // Triangles over corners.
    let mut tris: Vec<[usize; 3]> = Vec::new();
    let mut local: Vec<[usize; 3]> = Vec::new();
    let mut pts: Vec<Vec3> = Vec::new();
    let mut at = 0usize;
    let arities: Box<dyn Iterator<Item = usize>> = if m.face_arities.is_empty() {
        Box::new(std::iter::repeat_n(3, corners / 3))
    } else {
        Box::new(m.face_arities.iter().map(|&a| a as usize))
    };
    for k in arities {
        let end = at
            .checked_add(k)
            .filter(|&e| e <= corners)
            .ok_or("face past the indices")?;
        if k >= 3 {
            pts.clear();
            for c in at..end {
                pts.push(positions[position_of(c)?]);
            }
            local.clear();
            triangulate(&pts, &mut local);
            tris.extend(local.iter().map(|t| t.map(|i| at + i)));
        }
        at = end;
    }

    // Area-weighted normals per position, so that uv seams do not split the shading.
    let mut acc = vec![Vec3::ZERO; np];
    for t in &tris {
        let [a, b, c] = [position_of(t[0])?, position_of(t[1])?, position_of(t[2])?];
        let n = (positions[b] - positions[a]).cross(positions[c] - positions[a]);
        if n.is_finite() {
            acc[a] += n;
            acc[b] += n;
            acc[c] += n;
        }
    }

    if has_uv && out.uvs.len() < out.positions.len() {
        out.uvs.resize(out.positions.len(), Vec2::ZERO);
    }
    let uv_wanted = has_uv || !out.uvs.is_empty();
    let mut vertex_of: HashMap<(u32, u32, u32), u32> = HashMap::new();
    let mut vertex = |c: usize, out: &mut TriangleMesh| -> Result<u32, String> {
        let p = position_of(c)?;
        let t = if has_uv {
            m.texcoord_indices[c]
        } else {
            u32::MAX
        };
        let n = if has_n { m.normal_indices[c] } else { u32::MAX };
        if let Some(&v) = vertex_of.get(&(p as u32, t, n)) {
            return Ok(v);
        }
        let id = u32::try_from(out.positions.len()).map_err(|_| "more than 2³² vertices")?;
        out.positions.push(positions[p]);
        let computed = unit(acc[p]).unwrap_or(Vec3::Z);
        let normal = if has_n {
            let n = n as usize;
            match m.normals.get(3 * n..3 * n + 3) {
                Some(v) => unit(Vec3::new(v[0], v[1], v[2])).unwrap_or(computed),
                None => return Err(format!("normal index {n} out of range")),
            }
        } else {
            computed
        };
        out.normals.push(normal);
        if uv_wanted {
            let uv = if has_uv {
                let t = t as usize;
                match m.texcoords.get(2 * t..2 * t + 2) {
                    Some(v) => Vec2::new(v[0], 1.0 - v[1]),
                    None => return Err(format!("texture coordinate index {t} out of range")),
                }
            } else {
                Vec2::ZERO
            };
            out.uvs.push(uv);
        }
        vertex_of.insert((p as u32, t, n), id);
        Ok(id)
    };
    for t in &tris {
        let tri = [vertex(t[0], out)?, vertex(t[1], out)?, vertex(t[2], out)?];
        out.triangles.push(tri);
        out.triangle_material.push(material);
    }
    Ok(())
}

/// A material as read from an MTL file.
struct MtlMaterial {
    name: String,
    params: MaterialParams,
    /// Resolved texture path, wrap mode, and `file:line` for messages.
    map_kd: Option<(PathBuf, Wrap, String)>,
}

/// The materials of every `mtllib` in the order `tobj` numbers them.
#[derive(Default)]
struct Libraries {
    materials: Vec<MtlMaterial>,
    warnings: Vec<String>,
}

impl Libraries {
    /// `tobj`'s material loader: parses the library (or libraries, when a `mtllib` line
    /// names several files) and returns the names in the order they were appended here.
    fn load(&mut self, base: &Path, mtl: &Path) -> tobj::MTLLoadResult {
        let text = mtl.to_string_lossy();
        if text.trim().is_empty() {
            self.warnings
                .push("`mtllib` without a file name ignored".to_string());
            return Err(tobj::LoadError::OpenFileFailed);
        }
        let whole = resolve(base, &text);
        let mut files = vec![whole.clone()];
        if !whole.is_file() && text.split_whitespace().count() > 1 {
            files = text.split_whitespace().map(|f| resolve(base, f)).collect();
        }
        for f in &mut files {
            // A library named with another extension (`x.mat`) when `x.mtl` exists.
            let alt = f.with_extension("mtl");
            if !f.is_file() && alt.is_file() {
                self.warnings.push(format!(
                    "material library {} not found; using {}",
                    f.display(),
                    alt.display()
                ));
                *f = alt;
            }
        }
        let mut names: Vec<tobj::Material> = Vec::new();
        for f in files {
            match std::fs::read(&f) {
                Ok(bytes) => {
                    for m in parse_mtl(&bytes, &f, &mut self.warnings) {
                        names.push(tobj::Material {
                            name: m.name.clone(),
                            ..Default::default()
                        });
                        self.materials.push(m);
                    }
                }
                Err(e) => self.warnings.push(format!(
                    "material library {}: {e}; its materials are replaced by the default",
                    f.display()
                )),
            }
        }
        // Later definitions of a name win, as in tobj.
        let map = names
            .iter()
            .enumerate()
            .map(|(i, m)| (m.name.clone(), i))
            .collect();
        Ok((names, map))
    }
}

/// Parses an MTL file leniently: unreadable statements become warnings.
fn parse_mtl(bytes: &[u8], file: &Path, warnings: &mut Vec<String>) -> Vec<MtlMaterial> {
    let text = String::from_utf8_lossy(bytes);
    let dir = file.parent().unwrap_or(Path::new("."));
    let mut out: Vec<MtlMaterial> = Vec::new();
    // Per material: whether `d` was given (it takes precedence over `Tr`).
    let mut has_d = false;
    for (i, line) in text.lines().enumerate() {
        let place = format!("{}:{}", file.display(), i + 1);
        let line = line.trim();
        let (key, rest) = match line.split_once(|c: char| c.is_whitespace()) {
            Some((k, r)) => (k, r.trim()),
            None => (line, ""),
        };
        if key.is_empty() || key.starts_with('#') {
            continue;
        }
        let key = key.to_ascii_lowercase();
        if key == "newmtl" {
            let name = if rest.is_empty() {
                warnings.push(format!("{place}: `newmtl` without a name"));
                "(unnamed)".to_string()
            } else {
                rest.to_string()
            };
            let mut params = MaterialParams::default_grey();
            params.diffuse = 1.0;
            out.push(MtlMaterial {
                name,
                params,
                map_kd: None,
            });
            has_d = false;
            continue;
        }
        let Some(m) = out.last_mut() else { continue };
        // Numeric arguments, up to an end-of-line `#` comment.
        let args = || rest.split_whitespace().take_while(|w| !w.starts_with('#'));
        let numbers = || -> Option<Vec<f32>> {
            args()
                .map(|w| w.parse::<f32>().ok().filter(|x| x.is_finite()))
                .collect()
        };
        let colour = || -> Option<Vec3> {
            let v = numbers()?;
            match v.as_slice() {
                [g] => Some(Vec3::splat(*g)),
                [r, g, b, ..] => Some(Vec3::new(*r, *g, *b)),
                _ => None,
            }
            .map(|c| c.max(Vec3::ZERO))
        };
        let scalar = || -> Option<f32> {
            // The last argument: `d -halo 0.5` has an option first.
            args()
                .filter(|w| !w.starts_with('-') || w.parse::<f32>().is_ok())
                .last()
                .and_then(|w| w.parse::<f32>().ok())
                .filter(|x| x.is_finite())
        };
        let bad = |what: &str, warnings: &mut Vec<String>| {
            warnings.push(format!("{place}: cannot read `{what} {rest}`; ignored"))
        };
        match key.as_str() {
            "kd" => match colour() {
                Some(c) => m.params.color = c,
                None => bad("Kd", warnings),
            },
            "ks" => match colour() {
                Some(c) => m.params.specular = c,
                None => bad("Ks", warnings),
            },
            "ns" => match scalar() {
                Some(x) => m.params.shininess = x.max(1.0),
                None => bad("Ns", warnings),
            },
            "ni" => match scalar() {
                Some(x) if x > 0.0 => m.params.ior = x,
                Some(x) => warnings.push(format!(
                    "{place}: `Ni {x}` is not an index of refraction; {} kept",
                    m.params.ior
                )),
                None => bad("Ni", warnings),
            },
            "d" => match scalar() {
                Some(x) => {
                    m.params.transparency = (1.0 - x).clamp(0.0, 1.0);
                    has_d = true;
                }
                None => bad("d", warnings),
            },
            "tr" if !has_d => match scalar() {
                // Some exporters (Meshlab) write `Tr 1` meaning opaque: a fully transparent
                // material is useless, so that value is read their way.
                Some(x) if x >= 1.0 => {
                    warnings.push(format!(
                        "{place}: `Tr {rest}` would make {} invisible; read as opaque",
                        m.name
                    ));
                    m.params.transparency = 0.0;
                }
                Some(x) => m.params.transparency = x.clamp(0.0, 1.0),
                None => bad("Tr", warnings),
            },
            "map_kd" => match texture_argument(rest) {
                Some((name, wrap)) => {
                    let path = resolve(dir, &name);
                    m.map_kd = Some((path, wrap, place.clone()));
                }
                None => bad("map_Kd", warnings),
            },
            _ => {}
        }
    }
    out
}

/// The file name and wrap mode of a texture statement's arguments (`-o 0 0 -clamp on name`).
fn texture_argument(rest: &str) -> Option<(String, Wrap)> {
    // Options and how many arguments they take (at most; -o, -s, -t take 1 to 3 numbers).
    const OPTIONS: &[(&str, usize)] = &[
        ("-blendu", 1),
        ("-blendv", 1),
        ("-bm", 1),
        ("-boost", 1),
        ("-cc", 1),
        ("-clamp", 1),
        ("-imfchan", 1),
        ("-mm", 2),
        ("-o", 3),
        ("-s", 3),
        ("-t", 3),
        ("-texres", 1),
        ("-type", 1),
    ];
    let mut wrap = Wrap::Repeat;
    let mut s = rest.trim_start();
    loop {
        let word = s.split_whitespace().next()?;
        let Some(&(opt, max)) = OPTIONS.iter().find(|(o, _)| o.eq_ignore_ascii_case(word)) else {
            break;
        };
        s = s[word.len()..].trim_start();
        for k in 0..max {
            let Some(arg) = s.split_whitespace().next() else {
                break;
            };
            let numeric = arg.parse::<f32>().is_ok();
            // -o/-s/-t take 1–3 numbers; other options take exactly `max` words.
            if (opt == "-o" || opt == "-s" || opt == "-t") && k > 0 && !numeric {
                break;
            }
            if opt == "-clamp" && arg.eq_ignore_ascii_case("on") {
                wrap = Wrap::ClampToEdge;
            }
            s = s[arg.len()..].trim_start();
        }
    }
    let name = s.trim();
    (!name.is_empty()).then(|| (name.to_string(), wrap))
}

/// A file named in an OBJ or MTL file, relative to `dir`: as written, else with backslashes
/// read as separators, else matched case-insensitively in its folder (files written on
/// Windows). The name as written when none exists.
fn resolve(dir: &Path, name: &str) -> PathBuf {
    let direct = dir.join(name);
    if direct.is_file() {
        return direct;
    }
    let slashed = dir.join(name.replace('\\', "/"));
    if slashed.is_file() {
        return slashed;
    }
    if let (Some(parent), Some(file)) = (slashed.parent(), slashed.file_name()) {
        let want = file.to_string_lossy().to_lowercase();
        if let Ok(rd) = std::fs::read_dir(parent) {
            for entry in rd.flatten() {
                if entry.file_name().to_string_lossy().to_lowercase() == want
                    && entry.path().is_file()
                {
                    return entry.path();
                }
            }
        }
    }
    direct
}

fn load_texture(path: &Path, wrap: Wrap) -> Result<super::Texture, String> {
    let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    texture::decode(&bytes, None, name, wrap, wrap)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_options_are_skipped() {
        assert_eq!(
            texture_argument("-o 0.5 0.5 -clamp on fuze uv.jpg"),
            Some(("fuze uv.jpg".to_string(), Wrap::ClampToEdge))
        );
        assert_eq!(
            texture_argument("-s 2 tex.png"),
            Some(("tex.png".to_string(), Wrap::Repeat))
        );
        assert_eq!(texture_argument("-bm 0.3"), None);
    }

    #[test]
    fn prescan_reports_lines() {
        let e = prescan(b"v 0 0 0\nv 1 0 0\nf 1 2 3\n").err().unwrap();
        assert_eq!(e.0, 3);
        let e = prescan(b"v 0 0 0\nf -2 1 1\n").err().unwrap();
        assert_eq!(e.0, 2);
        let e = prescan(b"v 0 0 nan\n").err().unwrap();
        assert_eq!(e.0, 1);
        assert!(
            prescan(b"v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
                .unwrap()
                .mixed_colors
                .is_some()
        );
    }
}
