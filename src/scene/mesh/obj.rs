//! Wavefront OBJ with MTL material libraries, read by a line-based parser of our own.
//!
//! Statements read: `v` (x y z, with an optional w that divides them, or x y z r g b: vertex
//! colours, which the renderer does not use), `vt`, `vn`, `f` (indices `v`, `v/vt`, `v//vn`,
//! `v/vt/vn`, negative ones relative to the end of the list so far; polygons kept whole and
//! split by ear clipping), `o` and `g` (the name of the following faces; faces of one name form
//! one mesh), `usemtl` and `mtllib`; `l` and `p` are checked and skipped, `s` and unknown
//! statements ignored. A line ending in `\` continues on the next; `#` starts a comment where
//! a word starts. Every error names the file and the line.
//!
//! Why not a library: `tobj`, which this module used, reports no line numbers, reads `l`
//! statements with three or more points as faces, misreads vertex colours given on only some
//! `v` lines, knows no line continuations and no comments after a statement, and invents
//! texture coordinates and normals for face corners that give none (those of another corner).
//! Checking the text first and rewriting it to steer `tobj` past those cases was a second
//! parser anyway.
//!
//! MTL files are parsed here, leniently: a missing or unreadable library or texture is a
//! warning, never a failure.

use super::polygon::triangulate;
use super::texture::{self, Wrap};
use super::{MeshAsset, MeshError, MeshInstance, MeshMaterial, TriangleMesh, unit};
use crate::scene::material::MaterialParams;
use glam::{Affine3A, Vec2, Vec3};
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
    let base = file.parent().unwrap_or(Path::new(".")).to_path_buf();
    let mut libs = Libraries::default();
    let obj =
        parse(bytes, &mut |name| libs.load(&base, name)).map_err(|(line, m)| err(Some(line), m))?;
    if obj.v_lines == 0 && obj.faces == 0 {
        return Err(err(
            None,
            "no vertices and no faces (not an OBJ file?)".into(),
        ));
    }

    let mut asset = MeshAsset::empty();
    asset.warnings.extend(std::mem::take(&mut libs.warnings));
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
            textures: super::MaterialTextures {
                base_color: base_color_texture.map(|texture| super::TextureRef {
                    texture,
                    tex_coord: 0,
                    transform: super::UvTransform::IDENTITY,
                }),
                ..Default::default()
            },
            alpha_mode: super::AlphaMode::Opaque,
            base_alpha: 1.0,
        });
    }
    for (name, line) in &obj.usemtl {
        if !libs.by_name.contains_key(name) {
            asset.warnings.push(format!(
                "{}:{line}: usemtl {name}: no such material in the loaded libraries; the \
                 default material is used",
                file.display()
            ));
        }
    }
    if obj.lines > 0 || obj.points > 0 {
        asset.warnings.push(format!(
            "{}: {} line and {} point elements skipped (only faces are drawn)",
            file.display(),
            obj.lines,
            obj.points
        ));
    }
    for line in &obj.empty_usemtl {
        asset.warnings.push(format!(
            "{}:{line}: `usemtl` without a name; the default material is used",
            file.display()
        ));
    }
    if obj.not_utf8.0 > 0 {
        asset.warnings.push(format!(
            "{}:{}: {} lines are not UTF-8; read with replacement characters",
            file.display(),
            obj.not_utf8.1,
            obj.not_utf8.0
        ));
    }
    if obj.small_faces > 0 {
        asset.warnings.push(format!(
            "{}: {} faces with fewer than 3 vertices skipped",
            file.display(),
            obj.small_faces
        ));
    }
    if let Some(line) = obj.mixed_colors {
        asset.warnings.push(format!(
            "{}:{line}: vertex colours on only some `v` lines; all vertex colours ignored",
            file.display()
        ));
    }

    let n_materials = libs.materials.len();
    let mut by_name: HashMap<String, usize> = HashMap::new();
    for group in &obj.groups {
        let name = if group.name.is_empty() || group.name == UNNAMED {
            stem.clone()
        } else {
            group.name.clone()
        };
        let slot = *by_name.entry(name.clone()).or_insert_with(|| {
            asset.meshes.push(TriangleMesh {
                name,
                ..TriangleMesh::default()
            });
            asset.meshes.len() - 1
        });
        let material = match group.material {
            Some(id) if id < n_materials => id as u32 + 1,
            _ => 0,
        };
        append_group(&mut asset.meshes[slot], &obj, group, material)
            .map_err(|(line, m)| err(Some(line), m))?;
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

/// The name of faces before any `o` or `g` statement, or after one without a name: the mesh
/// takes the file's stem.
const UNNAMED: &str = "unnamed_object";

/// A face corner's index that the file does not give (`v//vn` has no texture coordinate).
const MISSING: u32 = u32::MAX;

/// One face corner: 0-based indices into the position, texture-coordinate and normal lists.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct Corner {
    v: u32,
    vt: u32,
    vn: u32,
}

/// A run of faces with one name and one material: between two `o`, `g` or `usemtl`
/// statements that change them.
#[derive(Debug, Default)]
struct Group {
    name: String,
    /// Index into the libraries' materials (`None`: the default material).
    material: Option<usize>,
    /// The corners of every face, face after face.
    corners: Vec<Corner>,
    /// Per face: its number of corners and its line; faces with fewer than 3 corners are not
    /// kept.
    faces: Vec<(u32, usize)>,
    /// Whether an `f` statement was read since the group began (including faces skipped for
    /// having fewer than 3 corners): only then does a new name or material begin a new group.
    any_face: bool,
}

/// What the parser read.
#[derive(Debug, Default)]
struct Obj {
    positions: Vec<Vec3>,
    texcoords: Vec<Vec2>,
    normals: Vec<Vec3>,
    /// The groups in file order (a name can come back later: its faces join the same mesh).
    groups: Vec<Group>,
    v_lines: usize,
    faces: usize,
    lines: usize,
    points: usize,
    small_faces: usize,
    /// A line where a `v` statement's colours differ in presence from an earlier one.
    mixed_colors: Option<usize>,
    /// Every material name `usemtl` names, with the first line that names it.
    usemtl: Vec<(String, usize)>,
    /// Lines of `usemtl` statements without a name.
    empty_usemtl: Vec<usize>,
    /// How many lines are not UTF-8 (read with replacement characters), and the first.
    not_utf8: (usize, usize),
}

/// Statements, each with the line it starts on.
type Statements = Vec<(usize, String)>;

/// The statements of an OBJ file, one per line after joining lines continued with `\`, with
/// the line each starts on, comments (from a `#` that starts a word) removed; and how many
/// lines are not UTF-8, with the first.
fn statements(bytes: &[u8]) -> Result<(Statements, (usize, usize)), (usize, String)> {
    let mut out = Vec::new();
    let mut not_utf8 = (0, 0);
    let mut pending: Option<(usize, String)> = None;
    for (i, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let ln = i + 1;
        if raw.contains(&0) {
            return Err((
                ln,
                "contains NUL bytes: a binary file, not OBJ text".to_string(),
            ));
        }
        let text = String::from_utf8_lossy(raw);
        if let std::borrow::Cow::Owned(_) = text {
            if not_utf8.0 == 0 {
                not_utf8.1 = ln;
            }
            not_utf8.0 += 1;
        }
        let text = strip_comment(&text);
        let (start, mut line) = match pending.take() {
            Some((start, mut so_far)) => {
                so_far.push(' ');
                so_far.push_str(text);
                (start, so_far)
            }
            None => (ln, text.to_string()),
        };
        let end = line.trim_end();
        if let Some(head) = end.strip_suffix('\\') {
            line.truncate(head.len());
            pending = Some((start, line));
        } else {
            out.push((start, line));
        }
    }
    // A `\` on the last line continues nothing.
    out.extend(pending);
    Ok((out, not_utf8))
}

/// `line` up to a `#` at the start of a word (a comment); a `#` inside a word (`mat#2`) is
/// part of it.
fn strip_comment(line: &str) -> &str {
    let mut prev_space = true;
    for (i, c) in line.char_indices() {
        if c == '#' && prev_space {
            return &line[..i];
        }
        prev_space = c.is_whitespace();
    }
    line
}

/// Parses the OBJ text `bytes`; `mtllib` statements call `load_library` with the name they
/// give, which returns the name → material index map of every library loaded so far. The
/// error is (line, message).
fn parse(
    bytes: &[u8],
    load_library: &mut dyn FnMut(&str) -> HashMap<String, usize>,
) -> Result<Obj, (usize, String)> {
    let (statements, not_utf8) = statements(bytes)?;
    let mut o = Obj {
        not_utf8,
        ..Obj::default()
    };
    let mut with_color: Option<bool> = None;
    // Largest positive index per kind, with its line, checked against the totals at the end:
    // a face may name a vertex given later in the file.
    let mut max_ref = [(0usize, 0usize); 3];
    let mut materials: HashMap<String, usize> = HashMap::new();
    let mut seen_usemtl = std::collections::HashSet::new();
    let mut group = Group {
        name: UNNAMED.to_string(),
        ..Group::default()
    };
    for (ln, line) in &statements {
        let ln = *ln;
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        // The rest of the statement after its keyword (a name may contain spaces).
        let rest = || line.trim_start()[key.len()..].trim();
        let number = |w: &str, what: &str| {
            w.parse::<f32>()
                .map_err(|_| (ln, format!("`{key}`: cannot read {what}{w:?} as a number")))
        };
        // `vt` and `vn` take the first `n` numbers and ignore the rest (`vt u v w`).
        let floats = |words: std::str::SplitWhitespace, n: usize, what: &str| {
            let v: Vec<&str> = words.take(n).collect();
            if v.len() < n {
                return Err((ln, format!("`{key}` needs {n} numbers ({what})")));
            }
            v.iter()
                .map(|w| number(w, ""))
                .collect::<Result<Vec<f32>, _>>()
        };
        match key {
            "v" => {
                let words: Vec<&str> = words.collect();
                if words.len() < 3 {
                    return Err((ln, "`v` needs 3 coordinates".into()));
                }
                let mut xyz = [0f32; 3];
                for (k, w) in words[..3].iter().enumerate() {
                    xyz[k] = number(w, "")?;
                }
                let mut colored = false;
                match words.len() {
                    3 => {}
                    4 => {
                        // w is the weight of rational curves and surfaces (the OBJ spec's
                        // `v x y z w`); polygon vertices ignore it, as tinyobjloader and
                        // Blender do. It must still be a number.
                        number(words[3], "w ")?;
                    }
                    6 => {
                        for w in &words[3..] {
                            number(w, "colour ")?;
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
                    Some(c) if c != colored && o.mixed_colors.is_none() => {
                        o.mixed_colors = Some(ln)
                    }
                    _ => {}
                }
                o.v_lines += 1;
                o.positions.push(Vec3::from(xyz));
            }
            "vt" => {
                let uv = floats(words, 2, "u v")?;
                o.texcoords.push(Vec2::new(uv[0], uv[1]));
            }
            "vn" => {
                let n = floats(words, 3, "x y z")?;
                o.normals.push(Vec3::new(n[0], n[1], n[2]));
            }
            "f" | "l" => {
                let counts = [o.positions.len(), o.texcoords.len(), o.normals.len()];
                let first = group.corners.len();
                for token in words {
                    let c = corner(key, token, counts, &mut max_ref, ln)?;
                    if key == "f" {
                        group.corners.push(c);
                    }
                }
                if key == "l" {
                    o.lines += 1;
                    continue;
                }
                group.any_face = true;
                let n = group.corners.len() - first;
                if n < 3 {
                    group.corners.truncate(first);
                    o.small_faces += 1;
                } else {
                    let n = u32::try_from(n)
                        .map_err(|_| (ln, format!("`f` has {n} corners; at most 2³² − 1")))?;
                    group.faces.push((n, ln));
                    o.faces += 1;
                }
            }
            "p" => o.points += 1,
            "o" | "g" => {
                let name = match rest() {
                    "" => UNNAMED.to_string(),
                    name => name.to_string(),
                };
                let material = group.material;
                close(&mut o.groups, &mut group, name, material);
            }
            "mtllib" => materials = load_library(rest()),
            "usemtl" => {
                let name = rest();
                let material = if name.is_empty() {
                    o.empty_usemtl.push(ln);
                    None
                } else {
                    if seen_usemtl.insert(name.to_string()) {
                        o.usemtl.push((name.to_string(), ln));
                    }
                    materials.get(name).copied()
                };
                if material != group.material {
                    let name = group.name.clone();
                    close(&mut o.groups, &mut group, name, material);
                }
            }
            _ => {}
        }
    }
    o.groups.push(group);
    let totals = [o.positions.len(), o.texcoords.len(), o.normals.len()];
    for (kind, what) in ["positions", "texture coordinates", "normals"]
        .into_iter()
        .enumerate()
    {
        let (max, ln) = max_ref[kind];
        // Texture and normal indices are ignored when the file has none of them.
        let ignored = kind > 0 && totals[kind] == 0;
        if max > totals[kind] && !ignored {
            return Err((
                ln,
                format!(
                    "index {max} is out of range: the file has {} {what}",
                    totals[kind]
                ),
            ));
        }
    }
    for (kind, total) in totals.iter().enumerate().skip(1) {
        if *total == 0 {
            for g in &mut o.groups {
                for c in &mut g.corners {
                    *[&mut c.vt, &mut c.vn][kind - 1] = MISSING;
                }
            }
        }
    }
    Ok(o)
}

/// Gives the faces from here on the name `name` and the material `material`: the current
/// group is kept if it read a face, and a new one begins; otherwise it is renamed.
fn close(groups: &mut Vec<Group>, group: &mut Group, name: String, material: Option<usize>) {
    if group.any_face {
        groups.push(std::mem::take(group));
    }
    group.name = name;
    group.material = material;
}

/// One corner `token` of an `f` or `l` statement (`key`) on line `ln`, with `counts` the
/// positions, texture coordinates and normals read so far (negative indices count back from
/// there); positive indices raise `max_ref`, checked once the file is read.
fn corner(
    key: &str,
    token: &str,
    counts: [usize; 3],
    max_ref: &mut [(usize, usize); 3],
    ln: usize,
) -> Result<Corner, (usize, String)> {
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
    let mut index = [MISSING; 3];
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
            return Err((ln, format!("`{key}`: {what} index 0 (indices start at 1)")));
        }
        let i = if x < 0 {
            if x.unsigned_abs() > counts[kind] {
                return Err((
                    ln,
                    format!(
                        "`{key}`: relative {what} index {x} reaches before the first one ({} so \
                         far)",
                        counts[kind]
                    ),
                ));
            }
            counts[kind] - x.unsigned_abs()
        } else {
            let x = x as usize;
            if x > max_ref[kind].0 {
                max_ref[kind] = (x, ln);
            }
            x - 1
        };
        // An index past 2³² − 2 is past the end of any list (checked at the end of the file).
        index[kind] = u32::try_from(i).unwrap_or(MISSING - 1);
    }
    Ok(Corner {
        v: index[0],
        vt: index[1],
        vn: index[2],
    })
}

/// Appends a group's faces (triangulated) to `out`, all with `material`; the error is (line,
/// message).
fn append_group(
    out: &mut TriangleMesh,
    obj: &Obj,
    group: &Group,
    material: u32,
) -> Result<(), (usize, String)> {
    let corners = &group.corners;
    // The group's positions in the order its corners first name them, so that the normals
    // accumulate over the group alone.
    let mut local_of: HashMap<u32, usize> = HashMap::new();
    let mut positions: Vec<Vec3> = Vec::new();
    let local: Vec<usize> = corners
        .iter()
        .map(|c| {
            *local_of.entry(c.v).or_insert_with(|| {
                positions.push(obj.positions[c.v as usize]);
                positions.len() - 1
            })
        })
        .collect();
    let has_uv = corners.iter().any(|c| c.vt != MISSING);

    // Triangles over corners.
    let mut tris: Vec<[usize; 3]> = Vec::new();
    let mut tri_local: Vec<[usize; 3]> = Vec::new();
    let mut pts: Vec<Vec3> = Vec::new();
    let mut at = 0usize;
    for &(k, _) in &group.faces {
        let end = at + k as usize;
        pts.clear();
        pts.extend((at..end).map(|c| positions[local[c]]));
        tri_local.clear();
        triangulate(&pts, &mut tri_local);
        tris.extend(tri_local.iter().map(|t| t.map(|i| at + i)));
        at = end;
    }

    // Area-weighted normals per position, so that uv seams do not split the shading.
    let mut acc = vec![Vec3::ZERO; positions.len()];
    for t in &tris {
        let [a, b, c] = t.map(|c| local[c]);
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
    let mut vertex_of: HashMap<Corner, u32> = HashMap::new();
    let line = group.faces.first().map_or(0, |f| f.1);
    let mut vertex = |c: usize, out: &mut TriangleMesh| -> Result<u32, (usize, String)> {
        let corner = corners[c];
        if let Some(&v) = vertex_of.get(&corner) {
            return Ok(v);
        }
        let id = u32::try_from(out.positions.len())
            .map_err(|_| (line, "more than 2³² vertices".to_string()))?;
        let p = local[c];
        out.positions.push(positions[p]);
        let computed = unit(acc[p]).unwrap_or(Vec3::Z);
        let normal = match obj.normals.get(corner.vn as usize) {
            Some(&n) => unit(n).unwrap_or(computed),
            None => computed,
        };
        out.normals.push(normal);
        if uv_wanted {
            let uv = obj
                .texcoords
                .get(corner.vt as usize)
                .map_or(Vec2::ZERO, |t| Vec2::new(t.x, 1.0 - t.y));
            out.uvs.push(uv);
        }
        vertex_of.insert(corner, id);
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

/// The materials of every `mtllib`, numbered in the order they were read.
#[derive(Default)]
struct Libraries {
    materials: Vec<MtlMaterial>,
    /// Name → index into `materials`; a later definition of a name wins.
    by_name: HashMap<String, usize>,
    warnings: Vec<String>,
}

impl Libraries {
    /// Reads the library (or libraries, when a `mtllib` line names several files) `name`
    /// relative to `base`; returns the name → index map of every material read so far.
    fn load(&mut self, base: &Path, name: &str) -> HashMap<String, usize> {
        if name.trim().is_empty() {
            self.warnings
                .push("`mtllib` without a file name ignored".to_string());
            return self.by_name.clone();
        }
        let whole = resolve(base, name);
        let mut files = vec![whole.clone()];
        if !whole.is_file() && name.split_whitespace().count() > 1 {
            files = name.split_whitespace().map(|f| resolve(base, f)).collect();
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
        for f in files {
            match crate::scene::read::read(&f) {
                Ok(bytes) => {
                    for m in parse_mtl(&bytes, &f, &mut self.warnings) {
                        self.by_name.insert(m.name.clone(), self.materials.len());
                        self.materials.push(m);
                    }
                }
                Err(e) => self.warnings.push(format!(
                    "material library {}: {e}; its materials are replaced by the default",
                    f.display()
                )),
            }
        }
        self.by_name.clone()
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
    let bytes = crate::scene::read::read(path).map_err(|e| e.to_string())?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    texture::decode(&bytes, None, name, wrap, wrap, true)
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

    fn parse_text(text: &[u8]) -> Result<Obj, (usize, String)> {
        parse(text, &mut |_| HashMap::new())
    }

    const TRIANGLE: &[u8] = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n";

    #[test]
    fn errors_name_their_line() {
        let line = |text: &[u8]| parse_text(text).unwrap_err().0;
        assert_eq!(line(b"v 0 0 0\nv 1 0 0\nf 1 2 3\n"), 3);
        assert_eq!(line(b"v 0 0 0\nf -2 1 1\n"), 2);
        assert_eq!(line(b"v 0 0 nan\n"), 1);
        assert_eq!(line(b"v 1e39 0 0\n"), 1);
        assert_eq!(line(b"v 0 0 0\nvt 0\n"), 2);
        assert_eq!(line(b"v 0 0 0\n\nf 1 1 0\n"), 3);
        // A continued statement's line is the one it starts on.
        assert_eq!(line(b"v 0 0 0\nf 1 \\\n 1 9\n"), 2);
        // Indices too large for any list are errors, not allocations.
        let (ln, message) = parse_text(b"v 0 0 0\nf 1 1 99999999999999999999999\n").unwrap_err();
        assert_eq!(ln, 2, "{message}");
        let (ln, message) = parse_text(b"v 0 0 0\nf 1 1 4294967297\n").unwrap_err();
        assert_eq!(ln, 2);
        assert!(message.contains("out of range"), "{message}");
        assert!(parse_text(b"v 0 0 0\x00\n").is_err());
    }

    #[test]
    fn statements_are_read_as_written() {
        // An `l` with three points is a polyline, not a face.
        let o = parse_text(&[TRIANGLE, b"l 1 2 3\nf 1 2 3\n"].concat()).unwrap();
        assert_eq!((o.faces, o.lines), (1, 1));
        // Vertex colours on only some `v` lines.
        let o = parse_text(b"v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        assert_eq!(o.mixed_colors, Some(2));
        // Comments after statements and continued lines.
        let o = parse_text(b"v 0 0 0 # origin\nv 1 0 0\nv 0 1 0\nf 1 \\\r\n 2 3 # face\n").unwrap();
        assert_eq!(o.faces, 1);
        assert_eq!(o.groups.last().unwrap().corners.len(), 3);
        // Negative indices and the index forms.
        let o =
            parse_text(&[TRIANGLE, b"vt 0 0\nvn 0 0 1\nf -3/1/1 -2//1 -1/-1\n"].concat()).unwrap();
        let c = |v, vt, vn| Corner { v, vt, vn };
        assert_eq!(
            o.groups.last().unwrap().corners,
            [c(0, 0, 0), c(1, MISSING, 0), c(2, 0, MISSING)]
        );
        // Names and materials split the faces into groups; a name without faces renames.
        let mut libs = |_: &str| HashMap::from([("red".to_string(), 0)]);
        let text = [
            b"mtllib m.mtl\n",
            TRIANGLE,
            b"g a\ng b\nf 1 2 3\nusemtl red\nf 1 2 3\nusemtl red\nf 1 2 3\no c # object\nf 1 2 3\n",
        ]
        .concat();
        let o = parse(&text, &mut libs).unwrap();
        let groups: Vec<(&str, Option<usize>, usize)> = o
            .groups
            .iter()
            .map(|g| (g.name.as_str(), g.material, g.faces.len()))
            .collect();
        assert_eq!(
            groups,
            [("b", None, 1), ("b", Some(0), 2), ("c", Some(0), 1)]
        );
    }
}
