//! Mesh loading (`hytrace::scene::mesh`) against real files: the shared third-party assets
//! (`$HYTRACE_ASSETS`, default `../shared/assets`) and assimp's test models
//! (`/usr/share/assimp/models`, Debian package `assimp-testmodels`).
//!
//! Every candidate file is loaded once, on its own thread under `catch_unwind` with a 30 s
//! limit; the other tests read the results. Expected figures are computed independently: the
//! glTF JSON walked with the `gltf` crate's document API (and its own accessor reader for
//! bounds), OBJ face lines counted in the text, PLY files written here.

mod common;

use glam::{DMat4, DVec3, Mat4, Vec2, Vec3, Vec4};
use hytrace::scene::mesh::{
    CameraProjection, LightKind, MeshAsset, MeshError, Texture, Wrap, load,
};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock, mpsc};
use std::time::{Duration, Instant};

const LOAD_LIMIT: Duration = Duration::from_secs(30);
const ASSIMP: &str = "/usr/share/assimp/models";

/// How loading one file ended.
enum Outcome {
    Loaded(MeshAsset),
    Failed(String),
    Panicked(String),
    TimedOut,
}

struct Entry {
    path: PathBuf,
    outcome: Outcome,
    elapsed: Duration,
}

struct Corpus {
    assets: Option<PathBuf>,
    entries: Vec<Entry>,
}

impl Corpus {
    fn get(&self, path: &Path) -> Option<&Entry> {
        self.entries.iter().find(|e| e.path == path)
    }

    /// The loaded asset at `rel` under the shared assets, failing the test when it did not
    /// load; `None` when the assets are absent (already reported).
    fn asset(&self, rel: &str) -> Option<&MeshAsset> {
        let path = self.assets.as_ref()?.join(rel);
        match self.get(&path).map(|e| &e.outcome) {
            Some(Outcome::Loaded(a)) => Some(a),
            Some(Outcome::Failed(m)) => panic!("{rel} did not load: {m}"),
            Some(_) => panic!("{rel} panicked or hung"),
            None => panic!(
                "{rel} is not in the corpus (missing from {:?}?)",
                self.assets
            ),
        }
    }
}

/// A folder the tests need: reported loudly when missing, and an error under `CI=true`.
fn required_dir(path: PathBuf, what: &str) -> Option<PathBuf> {
    if path.is_dir() {
        return Some(path);
    }
    let msg = format!(
        "\n!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!\n\
         !!! {what} not found at {}\n\
         !!! tests using it are SKIPPED\n\
         !!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!\n",
        path.display()
    );
    eprintln!("{msg}");
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("CI=true and {what} is missing at {}", path.display());
    }
    None
}

fn assets_dir() -> Option<PathBuf> {
    required_dir(common::assets(), "the shared assets ($HYTRACE_ASSETS)")
}

fn assimp_dir() -> Option<PathBuf> {
    required_dir(
        PathBuf::from(ASSIMP),
        "assimp's test models (apt-get install assimp-testmodels; scripts/setup.sh)",
    )
}

fn collect(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    let mut items: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
    items.sort();
    for p in items {
        if p.is_dir() {
            collect(&p, out);
        } else if let Some(ext) = p.extension().and_then(|e| e.to_str())
            && ["gltf", "glb", "obj", "ply"].contains(&ext.to_ascii_lowercase().as_str())
        {
            out.push(p);
        }
    }
}

/// `load(path)` on its own thread, under `catch_unwind`, with a time limit.
fn guarded_load(path: &Path) -> (Outcome, Duration) {
    let (tx, rx) = mpsc::channel();
    let p = path.to_path_buf();
    let start = Instant::now();
    std::thread::spawn(move || {
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| load(&p)));
        let _ = tx.send(r);
    });
    let outcome = match rx.recv_timeout(LOAD_LIMIT) {
        Ok(Ok(Ok(asset))) => Outcome::Loaded(asset),
        Ok(Ok(Err(e))) => Outcome::Failed(e.to_string()),
        Ok(Err(payload)) => Outcome::Panicked(
            payload
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default(),
        ),
        Err(_) => Outcome::TimedOut,
    };
    (outcome, start.elapsed())
}

/// Every candidate file, loaded once (by a few worker threads).
fn corpus() -> &'static Corpus {
    static CORPUS: OnceLock<Corpus> = OnceLock::new();
    CORPUS.get_or_init(|| {
        let assets = assets_dir();
        let mut files = Vec::new();
        if let Some(a) = &assets {
            collect(a, &mut files);
        }
        if let Some(m) = assimp_dir() {
            for sub in ["glTF2", "OBJ", "PLY", "invalid"] {
                collect(&m.join(sub), &mut files);
            }
        }
        let queue = Mutex::new(files.clone().into_iter().enumerate());
        let results = Mutex::new(Vec::new());
        let workers = std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(2)
            .clamp(2, 4);
        std::thread::scope(|s| {
            for _ in 0..workers {
                s.spawn(|| {
                    loop {
                        let next = queue.lock().unwrap().next();
                        let Some((i, path)) = next else { break };
                        let (outcome, elapsed) = guarded_load(&path);
                        results.lock().unwrap().push((
                            i,
                            Entry {
                                path,
                                outcome,
                                elapsed,
                            },
                        ));
                    }
                });
            }
        });
        let mut entries = results.into_inner().unwrap();
        entries.sort_by_key(|(i, _)| *i);
        Corpus {
            assets,
            entries: entries.into_iter().map(|(_, e)| e).collect(),
        }
    })
}

fn short(path: &Path) -> String {
    let s = path.display().to_string();
    for prefix in [format!("{ASSIMP}/")]
        .into_iter()
        .chain(corpus().assets.iter().map(|a| format!("{}/", a.display())))
    {
        if let Some(rest) = s.strip_prefix(&prefix) {
            return rest.to_string();
        }
    }
    s
}

#[test]
fn every_file_loads_or_fails_with_a_message_naming_it() {
    let c = corpus();
    let mut problems = Vec::new();
    println!(
        "\n{:<78} {:>10} {:>10} {:>8}  result",
        "file", "triangles", "unique", "ms"
    );
    for e in &c.entries {
        let ms = e.elapsed.as_secs_f64() * 1000.0;
        let name = short(&e.path);
        match &e.outcome {
            Outcome::Loaded(a) => println!(
                "{name:<78} {:>10} {:>10} {ms:>8.1}  ok ({} meshes, {} instances, {} materials, \
                 {} textures, {} cameras, {} lights, {} warnings)",
                a.triangle_count(),
                a.unique_triangle_count(),
                a.meshes.len(),
                a.instances.len(),
                a.materials.len(),
                a.textures.len(),
                a.cameras.len(),
                a.lights.len(),
                a.warnings.len()
            ),
            Outcome::Failed(m) => {
                println!("{name:<78} {:>10} {:>10} {ms:>8.1}  error: {m}", "-", "-");
                if !m.contains(&e.path.display().to_string()) {
                    problems.push(format!("{name}: the error does not name the file: {m}"));
                }
                if m.contains('\n') || m.contains('\t') {
                    problems.push(format!("{name}: the error is not one line: {m:?}"));
                }
            }
            Outcome::Panicked(m) => {
                println!("{name:<78} PANIC: {m}");
                problems.push(format!("{name}: panicked: {m}"));
            }
            Outcome::TimedOut => {
                println!("{name:<78} TIMEOUT");
                problems.push(format!("{name}: took more than {LOAD_LIMIT:?}"));
            }
        }
    }
    println!("\nwarnings (first three per file):");
    for e in &c.entries {
        if let Outcome::Loaded(a) = &e.outcome {
            for w in a.warnings.iter().take(3) {
                println!("  {}: {w}", short(&e.path));
            }
        }
    }
    let loaded = c
        .entries
        .iter()
        .filter(|e| matches!(e.outcome, Outcome::Loaded(_)))
        .count();
    println!("{} files, {loaded} loaded\n", c.entries.len());
    for e in &c.entries {
        if let Outcome::Loaded(a) = &e.outcome {
            check_invariants(&short(&e.path), a, &mut problems);
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// What every loaded asset must satisfy, whatever the file.
fn check_invariants(name: &str, a: &MeshAsset, problems: &mut Vec<String>) {
    if a.materials.is_empty() || a.materials[0].name != "(default)" {
        problems.push(format!("{name}: material 0 is not the default"));
    }
    for (mi, m) in a.meshes.iter().enumerate() {
        let nv = m.positions.len();
        let mut bad = Vec::new();
        if m.normals.len() != nv || !(m.uvs.is_empty() || m.uvs.len() == nv) {
            bad.push("attribute counts differ".to_string());
        }
        if m.triangle_material.len() != m.triangles.len() {
            bad.push("triangle_material has the wrong length".to_string());
        }
        if !m.triangles.iter().flatten().all(|&i| (i as usize) < nv) {
            bad.push("vertex index out of range".to_string());
        }
        if !m
            .triangle_material
            .iter()
            .all(|&t| (t as usize) < a.materials.len())
        {
            bad.push("material index out of range".to_string());
        }
        if !m.positions.iter().all(|p| p.is_finite()) {
            bad.push("non-finite position".to_string());
        }
        if let Some(n) = m
            .normals
            .iter()
            .find(|n| !n.is_finite() || (n.length() - 1.0).abs() > 1e-3)
        {
            bad.push(format!("normal {n:?} is not unit"));
        }
        if !bad.is_empty() {
            problems.push(format!(
                "{name}: mesh {mi} ({}): {}",
                m.name,
                bad.join(", ")
            ));
        }
    }
    for i in &a.instances {
        if i.mesh >= a.meshes.len() || !i.transform.is_finite() {
            problems.push(format!("{name}: instance {} is invalid", i.name));
        }
    }
    for m in &a.materials {
        if m.textures
            .slots()
            .iter()
            .flatten()
            .any(|t| t.texture >= a.textures.len())
        {
            problems.push(format!(
                "{name}: material {} has a bad texture index",
                m.name
            ));
        }
    }
    for t in &a.textures {
        if t.texels.len() != (t.width as usize) * (t.height as usize) || t.width == 0 {
            problems.push(format!("{name}: texture {} is inconsistent", t.name));
        }
    }
}

// ---------------------------------------------------------------- independent figures

/// The scene's root nodes as the glTF specification picks them.
fn gltf_roots(doc: &gltf::Document) -> Vec<gltf::Node<'_>> {
    match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => {
            let children: HashSet<usize> = doc
                .nodes()
                .flat_map(|n| n.children().map(|c| c.index()).collect::<Vec<_>>())
                .collect();
            doc.nodes()
                .filter(|n| !children.contains(&n.index()))
                .collect()
        }
    }
}

/// Every (node, world matrix) instance of the scene, in f64.
fn gltf_instances(doc: &gltf::Document) -> Vec<(gltf::Node<'_>, DMat4)> {
    let mut out = Vec::new();
    let mut stack: Vec<(gltf::Node, DMat4)> = gltf_roots(doc)
        .into_iter()
        .map(|n| (n, DMat4::IDENTITY))
        .collect();
    while let Some((n, parent)) = stack.pop() {
        let local = Mat4::from_cols_array_2d(&n.transform().matrix()).as_dmat4();
        let world = parent * local;
        for c in n.children() {
            stack.push((c, world));
        }
        out.push((n, world));
        assert!(out.len() < 10_000_000, "node graph too large");
    }
    out
}

fn drawn(mode: gltf::mesh::Mode) -> bool {
    use gltf::mesh::Mode::*;
    matches!(mode, Triangles | TriangleStrip | TriangleFan)
}

fn primitive_triangles(p: &gltf::Primitive) -> usize {
    use gltf::mesh::Mode::*;
    let n = match p.indices() {
        Some(a) => a.count(),
        None => p.get(&gltf::Semantic::Positions).map_or(0, |a| a.count()),
    };
    match p.mode() {
        Triangles => n / 3,
        TriangleStrip | TriangleFan => n.saturating_sub(2),
        _ => 0,
    }
}

/// The document as the `gltf` crate reads it, without its validation (which refuses POSITION
/// accessors without min/max, a requirement the loader relaxes).
fn open_gltf(path: &Path) -> Option<gltf::Gltf> {
    gltf::Gltf::from_slice_without_validation(&std::fs::read(path).ok()?).ok()
}

/// (instanced, unique) triangle counts from the JSON alone.
fn gltf_expected_counts(path: &Path) -> Option<(usize, usize)> {
    let g = open_gltf(path)?;
    let mut total = 0;
    let mut unique = 0;
    let mut seen = HashSet::new();
    for (node, _) in gltf_instances(&g.document) {
        if let Some(m) = node.mesh() {
            let t: usize = m.primitives().map(|p| primitive_triangles(&p)).sum();
            total += t;
            if seen.insert(m.index()) {
                unique += t;
            }
        }
    }
    Some((total, unique))
}

/// World bounds: every POSITION of every drawn primitive (read by the `gltf` crate's own
/// accessor reader) through its node's world matrix.
fn gltf_expected_bounds(path: &Path) -> Option<(DVec3, DVec3)> {
    let g = open_gltf(path)?;
    let buffers = gltf::import_buffers(&g.document, path.parent(), g.blob.clone()).ok()?;
    let mut lo = DVec3::INFINITY;
    let mut hi = DVec3::NEG_INFINITY;
    for (node, world) in gltf_instances(&g.document) {
        let Some(m) = node.mesh() else { continue };
        for p in m.primitives().filter(|p| drawn(p.mode())) {
            let reader = p.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            for q in reader.read_positions()? {
                let w = world.transform_point3(Vec3::from_array(q).as_dvec3());
                lo = lo.min(w);
                hi = hi.max(w);
            }
        }
    }
    Some((lo, hi))
}

/// Triangles of an OBJ counted from its text: n − 2 per `f` line with n ≥ 3 vertices.
fn obj_expected_triangles(path: &Path) -> usize {
    let text = String::from_utf8_lossy(&std::fs::read(path).unwrap()).into_owned();
    text.lines()
        .filter_map(|l| {
            let mut w = l.split_whitespace();
            (w.next() == Some("f")).then(|| w.count())
        })
        .filter(|&n| n >= 3)
        .map(|n| n - 2)
        .sum()
}

#[test]
fn gltf_triangle_counts_match_the_json() {
    let c = corpus();
    let mut checked = 0;
    let mut problems = Vec::new();
    for e in &c.entries {
        let ext = e.path.extension().unwrap().to_string_lossy().to_lowercase();
        let Outcome::Loaded(a) = &e.outcome else {
            continue;
        };
        if ext != "gltf" && ext != "glb" {
            continue;
        }
        let p = e.path.clone();
        let Ok(Some((total, unique))) = std::panic::catch_unwind(|| gltf_expected_counts(&p))
        else {
            println!(
                "{}: the gltf crate cannot open it; count not checked",
                short(&e.path)
            );
            continue;
        };
        checked += 1;
        if a.triangle_count() != total || a.unique_triangle_count() != unique {
            problems.push(format!(
                "{}: loaded {} / {} unique triangles, the JSON says {total} / {unique}",
                short(&e.path),
                a.triangle_count(),
                a.unique_triangle_count()
            ));
        }
    }
    println!("{checked} glTF files counted");
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn obj_triangle_counts_match_the_text() {
    let c = corpus();
    let mut problems = Vec::new();
    let mut checked = 0;
    for e in &c.entries {
        let ext = e.path.extension().unwrap().to_string_lossy().to_lowercase();
        let Outcome::Loaded(a) = &e.outcome else {
            continue;
        };
        if ext != "obj" {
            continue;
        }
        checked += 1;
        let want = obj_expected_triangles(&e.path);
        if a.triangle_count() != want || a.unique_triangle_count() != want {
            problems.push(format!(
                "{}: loaded {} triangles, the face lines give {want}",
                short(&e.path),
                a.triangle_count()
            ));
        }
    }
    println!("{checked} OBJ files counted");
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn counts_match_assets_md() {
    let c = corpus();
    let Some(assets) = &c.assets else { return };
    // The figures the task names, then every row of ASSETS.md when it is there.
    let mut expect: Vec<(String, usize, Option<usize>)> = [
        (
            "glTF/2CylinderEngine/glTF-Binary/2CylinderEngine.glb",
            121496,
            Some(75730),
        ),
        (
            "glTF/ReciprocatingSaw/glTF/ReciprocatingSaw.gltf",
            198470,
            Some(139594),
        ),
        (
            "glTF/MetalRoughSpheresNoTextures/glTF/MetalRoughSpheresNoTextures.gltf",
            1040409,
            None,
        ),
        ("obj/common-3d-test-models/stanford-bunny.obj", 69451, None),
        ("obj/cornell_box_tobj/cornell_box.obj", 36, None),
        ("glTF/Box/glTF/Box.gltf", 12, None),
        ("glTF/SimpleMeshes/glTF/SimpleMeshes.gltf", 2, Some(1)),
        (
            "glTF/TriangleWithoutIndices/glTF/TriangleWithoutIndices.gltf",
            1,
            None,
        ),
    ]
    .into_iter()
    .map(|(p, n, u)| (p.to_string(), n, u))
    .collect();
    let md = assets.join("../ASSETS.md");
    match std::fs::read_to_string(&md) {
        Ok(text) => {
            for line in text.lines() {
                let cols: Vec<&str> = line.split('|').map(str::trim).collect();
                if cols.len() < 4 || !(cols[1].starts_with("glTF/") || cols[1].starts_with("obj/"))
                {
                    continue;
                }
                let Ok(n) = cols[2].parse::<usize>() else {
                    continue;
                };
                let unique = cols[3]
                    .split("unique tris=")
                    .nth(1)
                    .and_then(|r| r.split(|c: char| !c.is_ascii_digit()).next())
                    .and_then(|d| d.parse().ok());
                expect.push((cols[1].to_string(), n, unique));
            }
        }
        Err(e) => println!(
            "{}: {e}; only the built-in figures are checked",
            md.display()
        ),
    }
    let mut problems = Vec::new();
    for (rel, n, unique) in &expect {
        let a = c.asset(rel).unwrap();
        let got = (a.triangle_count(), a.unique_triangle_count());
        println!(
            "{rel}: {} / {} unique (ASSETS.md {n} / {unique:?})",
            got.0, got.1
        );
        if got.0 != *n || unique.is_some_and(|u| u != got.1) {
            problems.push(format!("{rel}: got {got:?}, expected {n} / {unique:?}"));
        }
    }
    println!("{} figures checked", expect.len());
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn gltf_bounds_match_transformed_vertices() {
    let c = corpus();
    let mut problems = Vec::new();
    let mut checked = 0;
    for e in &c.entries {
        let ext = e.path.extension().unwrap().to_string_lossy().to_lowercase();
        let Outcome::Loaded(a) = &e.outcome else {
            continue;
        };
        if (ext != "gltf" && ext != "glb") || a.instances.is_empty() {
            continue;
        }
        let p = e.path.clone();
        let expected = std::panic::catch_unwind(|| gltf_expected_bounds(&p));
        let Ok(Some((lo, hi))) = expected else {
            println!(
                "{}: the gltf crate cannot read it; bounds not checked",
                short(&e.path)
            );
            continue;
        };
        checked += 1;
        let b = a.bounds();
        let scale = (hi - lo)
            .length()
            .max(lo.abs().max_element())
            .max(hi.abs().max_element());
        let tol = 1e-4 * scale.max(1e-12);
        let d = (b.min.as_dvec3() - lo)
            .abs()
            .max((b.max.as_dvec3() - hi).abs());
        if d.max_element() > tol {
            problems.push(format!(
                "{}: bounds {:?}..{:?}, expected {lo:?}..{hi:?}",
                short(&e.path),
                b.min,
                b.max
            ));
        }
    }
    println!("{checked} glTF bounds checked");
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

// ---------------------------------------------------------------- specific features

#[test]
fn box_textured_in_three_forms() {
    let c = corpus();
    if c.assets.is_none() {
        return;
    }
    let forms = [
        "glTF/BoxTextured/glTF/BoxTextured.gltf",
        "glTF/BoxTextured/glTF-Embedded/BoxTextured.gltf",
        "glTF/BoxTextured/glTF-Binary/BoxTextured.glb",
    ];
    let world_triangles = |a: &MeshAsset| -> Vec<[Vec3; 3]> {
        a.instances
            .iter()
            .flat_map(|i| {
                let m = &a.meshes[i.mesh];
                m.triangles
                    .iter()
                    .map(|t| t.map(|v| i.transform.transform_point3(m.positions[v as usize])))
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    let first = world_triangles(c.asset(forms[0]).unwrap());
    assert_eq!(first.len(), 12);
    for f in forms {
        let a = c.asset(f).unwrap();
        // The image as the gltf crate's own importer decodes it (the embedded form carries a
        // smaller copy of the logo).
        let (_, _, images) = gltf::import(c.assets.as_ref().unwrap().join(f)).unwrap();
        let (w, h) = (images[0].width, images[0].height);
        assert_eq!(world_triangles(a), first, "{f}: different triangles");
        assert_eq!(a.textures.len(), 1, "{f}");
        let t = &a.textures[0];
        assert_eq!((t.width, t.height), (w, h), "{f}: texture size");
        let m = &a.materials[1];
        assert_eq!(m.textures.base_color.map(|t| t.texture), Some(0), "{f}");
        assert_eq!(
            a.meshes[0].uvs.len(),
            a.meshes[0].positions.len(),
            "{f}: uvs"
        );
    }
}

#[test]
fn sparse_accessor_moves_the_vertices() {
    let c = corpus();
    let Some(assets) = &c.assets else { return };
    let rel = "glTF/SimpleSparseAccessor/glTF/SimpleSparseAccessor.gltf";
    let a = c.asset(rel).unwrap();
    let path = assets.join(rel);
    // Read the sparse substitution from the JSON and the .bin directly.
    let g = gltf::Gltf::open(&path).unwrap();
    let json = g.document.as_json();
    let (ai, acc) = json
        .accessors
        .iter()
        .enumerate()
        .find(|(_, a)| a.sparse.is_some())
        .expect("a sparse accessor");
    let sparse = acc.sparse.as_ref().unwrap();
    let bin = std::fs::read(
        path.parent()
            .unwrap()
            .join(json.buffers[0].uri.as_ref().unwrap()),
    )
    .unwrap();
    let view = |v: usize| {
        let bv = &json.buffer_views[v];
        let off = bv.byte_offset.map_or(0, |o| o.0) as usize;
        &bin[off..off + bv.byte_length.0 as usize]
    };
    let idata = &view(sparse.indices.buffer_view.value())[sparse.indices.byte_offset.0 as usize..];
    let vdata = &view(sparse.values.buffer_view.value())[sparse.values.byte_offset.0 as usize..];
    let isize = match sparse.indices.component_type.as_ref().unwrap().0 {
        gltf::json::accessor::ComponentType::U8 => 1,
        gltf::json::accessor::ComponentType::U16 => 2,
        _ => 4,
    };
    let mesh = &a.meshes[0];
    // The primitive has no NORMAL, so its normals are flat (glTF 2.0 §3.7.2.1): each
    // triangle's corners are vertices of their own, copied from the accessor's.
    assert!(acc.count.0 > 0, "accessors[{ai}] count");
    assert_eq!(mesh.positions.len(), 3 * mesh.triangles.len());
    let n = sparse.count.0 as usize;
    assert!(n > 0);
    for k in 0..n {
        let ib = &idata[k * isize..(k + 1) * isize];
        let target = match isize {
            1 => ib[0] as usize,
            2 => u16::from_le_bytes([ib[0], ib[1]]) as usize,
            _ => u32::from_le_bytes([ib[0], ib[1], ib[2], ib[3]]) as usize,
        };
        let f = |c: usize| {
            let b = &vdata[k * 12 + 4 * c..k * 12 + 4 * c + 4];
            f32::from_le_bytes([b[0], b[1], b[2], b[3]])
        };
        let want = Vec3::new(f(0), f(1), f(2));
        assert!(
            mesh.positions.contains(&want),
            "vertex {target}: {want} is not among the mesh's positions"
        );
    }
}

#[test]
fn obj_features() {
    let c = corpus();
    if c.assets.is_none() {
        return;
    }
    let cornell = c.asset("obj/cornell_box_tobj/cornell_box.obj").unwrap();
    assert_eq!(cornell.triangle_count(), 36);
    assert!(
        cornell.materials.len() > 5,
        "cornell_box: {} materials",
        cornell.materials.len() - 1
    );
    let used: HashSet<u32> = cornell
        .meshes
        .iter()
        .flat_map(|m| m.triangle_material.iter().copied())
        .collect();
    // Five materials over two libraries; the blue wall's face is commented out.
    let names: HashSet<&str> = cornell.materials.iter().map(|m| m.name.as_str()).collect();
    for n in ["white", "red", "green", "blue", "light"] {
        assert!(names.contains(n), "cornell_box: no material {n}");
    }
    assert!(used.len() >= 4, "cornell_box uses {used:?}");
    // Its .mtl names textures that do not exist: warnings, not failures.
    assert!(
        cornell
            .warnings
            .iter()
            .any(|w| w.contains("dummy_texture.png"))
    );

    let poly = c.asset("obj/trimesh/polygonfaces.obj").unwrap();
    assert_eq!(poly.triangle_count(), 3);
    assert!(
        poly.warnings.iter().any(|w| w.contains("surface.mtl")),
        "{:?}",
        poly.warnings
    );
    let knot = c.asset("obj/trimesh/quadknot.obj").unwrap();
    assert_eq!(knot.triangle_count(), 2880);
    let cube = c
        .asset("obj/tinyobjloader/cube-vertex-w-component.obj")
        .unwrap();
    assert_eq!(cube.triangle_count(), 12);
    // The fourth coordinate is a rational weight, not a homogeneous divisor: the cube keeps
    // its corners at 0 and 2.
    let b = cube.bounds();
    assert_eq!(
        (b.min, b.max),
        (Vec3::ZERO, Vec3::splat(2.0)),
        "cube-vertex-w-component"
    );
    let fuze = c.asset("obj/trimesh/fuze.obj").unwrap();
    assert_eq!(fuze.textures.len(), 1, "fuze uv.jpg (a space in the name)");
    let bunny = c
        .asset("obj/common-3d-test-models/stanford-bunny.obj")
        .unwrap();
    assert_eq!(bunny.triangle_count(), 69451);
}

fn signed_area(m: &hytrace::scene::mesh::TriangleMesh, normal: Vec3) -> Vec<f32> {
    m.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| m.positions[i as usize]);
            0.5 * (b - a).cross(c - a).dot(normal)
        })
        .collect()
}

/// L-shaped hexagon, area 3, listed from a corner from which a fan would leave the polygon.
const L_SHAPE: [(f32, f32); 6] = [(2., 1.), (1., 1.), (1., 2.), (0., 2.), (0., 0.), (2., 0.)];

#[test]
fn concave_obj_polygon_is_covered_exactly() {
    let dir_tmp = common::temp_dir("mesh-concave");
    let dir = dir_tmp.path().to_path_buf();
    let path = dir.join("l_shape.obj");
    let mut text = String::from("# L-shaped hexagon\n");
    for (x, y) in L_SHAPE {
        text += &format!("v {x} {y} 0\n");
    }
    text += "f 1 2 3 4 5 6\n";
    std::fs::write(&path, &text).unwrap();
    let crlf = dir.join("l_shape_crlf.obj");
    std::fs::write(&crlf, text.replace('\n', "\r\n")).unwrap();
    assert_eq!(load(&crlf).unwrap().triangle_count(), 4);
    let a = load(&path).unwrap();
    assert_eq!(a.triangle_count(), 4);
    let areas = signed_area(&a.meshes[0], Vec3::Z);
    assert!(
        areas.iter().all(|&s| s > 0.0),
        "flipped triangle: {areas:?}"
    );
    assert!((areas.iter().sum::<f32>() - 3.0).abs() < 1e-5, "{areas:?}");
    // Computed normals face +Z (counter-clockwise seen from +Z).
    assert!(
        a.meshes[0]
            .normals
            .iter()
            .all(|n| n.abs_diff_eq(Vec3::Z, 1e-6))
    );
}

#[test]
fn gltf_cameras_and_lights() {
    let c = corpus();
    if c.assets.is_none() {
        return;
    }
    let cams = c.asset("glTF/Cameras/glTF/Cameras.gltf").unwrap();
    let persp = cams
        .cameras
        .iter()
        .filter(|c| matches!(c.projection, CameraProjection::Perspective { .. }))
        .count();
    let ortho = cams
        .cameras
        .iter()
        .filter(|c| matches!(c.projection, CameraProjection::Orthographic { .. }))
        .count();
    assert_eq!((persp, ortho), (1, 1), "{:?}", cams.cameras);
    for cam in &cams.cameras {
        assert!((cam.forward.length() - 1.0).abs() < 1e-5);
        assert!(cam.forward.dot(cam.up).abs() < 1e-5);
    }
    let cubes = c.asset("glTF/bevy-lights/Cubes.glb").unwrap();
    assert!(
        cubes
            .lights
            .iter()
            .any(|l| matches!(l.kind, LightKind::Point { .. })),
        "{:?}",
        cubes.lights
    );
    let dof = c.asset("glTF/bevy-lights/DepthOfFieldExample.glb").unwrap();
    let dir = dof
        .lights
        .iter()
        .find_map(|l| match l.kind {
            LightKind::Directional { direction } => Some(direction),
            _ => None,
        })
        .expect("a directional light");
    assert!((dir.length() - 1.0).abs() < 1e-5);
}

#[test]
fn triangle_strips_and_fans_keep_their_winding() {
    let Some(m) = assimp_dir() else { return };
    let c = corpus();
    let mut checked = 0;
    for i in 0..16 {
        let p = m.join(format!(
            "glTF2/glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_{i:02}.gltf"
        ));
        let Some(Outcome::Loaded(a)) = c.get(&p).map(|e| &e.outcome) else {
            continue;
        };
        for mesh in &a.meshes {
            let normals: Vec<Vec3> = mesh
                .triangles
                .iter()
                .map(|t| {
                    let [x, y, z] = t.map(|i| mesh.positions[i as usize]);
                    (y - x).cross(z - x)
                })
                .filter(|n| n.length() > 1e-9)
                .collect();
            for n in &normals {
                assert!(
                    n.dot(normals[0]) > 0.0,
                    "{}: triangles of a flat mesh face different ways",
                    p.display()
                );
            }
            checked += 1;
        }
    }
    println!("{checked} primitive-mode meshes checked");
}

// ---------------------------------------------------------------- PLY

/// Five vertices (unit square at z = 0 and an apex) with uvs, a quad and a triangle.
const PLY_POINTS: [[f64; 5]; 5] = [
    [0., 0., 0., 0., 0.],
    [1., 0., 0., 1., 0.],
    [1., 1., 0., 1., 1.],
    [0., 1., 0., 0., 1.],
    [0.5, 0.5, 1., 0.5, 0.5],
];
const PLY_FACES: [&[u32]; 2] = [&[0, 1, 2, 3], &[0, 1, 4]];

fn ply_ascii() -> Vec<u8> {
    let mut s = String::from(
        "ply\nformat ascii 1.0\ncomment written by the mesh tests\nelement vertex 5\n\
         property double x\nproperty double y\nproperty double z\nproperty float s\n\
         property float t\nelement face 2\nproperty list uchar int vertex_index\nend_header\n",
    );
    for p in PLY_POINTS {
        s += &format!("{} {} {} {} {}\n", p[0], p[1], p[2], p[3], p[4]);
    }
    for f in PLY_FACES {
        s += &format!("{}", f.len());
        for i in f {
            s += &format!(" {i}");
        }
        s += "\n";
    }
    s.into_bytes()
}

/// Little endian: properties in the order z x y, float; faces `list uchar uint` followed by
/// a per-face byte; an extra element after the faces.
fn ply_binary_le() -> Vec<u8> {
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float z\n\
        property float x\nproperty float y\nproperty float u\nproperty float v\n\
        element face 2\nproperty list uchar uint vertex_indices\nproperty uchar flags\n\
        element extra 1\nproperty int value\nend_header\n"
        .to_vec();
    for p in PLY_POINTS {
        for c in [p[2], p[0], p[1], p[3], p[4]] {
            b.extend((c as f32).to_le_bytes());
        }
    }
    for f in PLY_FACES {
        b.push(f.len() as u8);
        for i in f {
            b.extend(i.to_le_bytes());
        }
        b.push(7);
    }
    b.extend(42i32.to_le_bytes());
    b
}

/// Big endian: double coordinates, `list int ushort` indices.
fn ply_binary_be() -> Vec<u8> {
    let mut b = b"ply\nformat binary_big_endian 1.0\nelement vertex 5\nproperty double x\n\
        property double y\nproperty double z\nproperty double texture_u\n\
        property double texture_v\nelement face 2\nproperty list int ushort vertex_indices\n\
        end_header\n"
        .to_vec();
    for p in PLY_POINTS {
        for c in p {
            b.extend(c.to_be_bytes());
        }
    }
    for f in PLY_FACES {
        b.extend((f.len() as i32).to_be_bytes());
        for &i in f.iter() {
            b.extend((i as u16).to_be_bytes());
        }
    }
    b
}

#[test]
fn ply_ascii_and_binary_agree() {
    let dir_tmp = common::temp_dir("mesh-ply");
    let dir = dir_tmp.path().to_path_buf();
    let mut first: Option<MeshAsset> = None;
    for (name, bytes) in [
        ("ascii.ply", ply_ascii()),
        (
            "ascii_crlf.ply",
            String::from_utf8(ply_ascii())
                .unwrap()
                .replace('\n', "\r\n")
                .into_bytes(),
        ),
        ("binary_le.PLY", ply_binary_le()),
        ("binary_be.ply", ply_binary_be()),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        let a = load(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(a.triangle_count(), 3, "{name}");
        let m = &a.meshes[0];
        assert_eq!(m.positions.len(), 5, "{name}");
        for (p, want) in m.positions.iter().zip(PLY_POINTS) {
            assert_eq!(
                *p,
                Vec3::new(want[0] as f32, want[1] as f32, want[2] as f32)
            );
        }
        // v is flipped so that (0, 0) is the image's top-left corner.
        assert_eq!(m.uvs[2], Vec2::new(1.0, 0.0), "{name}");
        let areas = signed_area(m, Vec3::Z);
        assert!(
            (areas[0] + areas[1] - 1.0).abs() < 1e-6,
            "{name}: quad {areas:?}"
        );
        let b = a.bounds();
        assert_eq!((b.min, b.max), (Vec3::ZERO, Vec3::ONE), "{name}");
        if let Some(f) = &first {
            assert_eq!(f.meshes[0].triangles, m.triangles, "{name}");
        } else {
            first = Some(a);
        }
    }
}

#[test]
fn concave_ply_face_and_normals() {
    let dir_tmp = common::temp_dir("mesh-ply-concave");
    let dir = dir_tmp.path().to_path_buf();
    let mut s = String::from(
        "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\n\
         property float z\nproperty float nx\nproperty float ny\nproperty float nz\n\
         element face 1\nproperty list uchar uint vertex_indices\nend_header\n",
    );
    for (i, (x, y)) in L_SHAPE.iter().enumerate() {
        // One zero normal: replaced by a computed one.
        let n = if i == 0 { "0 0 0" } else { "0 0 2" };
        s += &format!("{x} {y} 0 {n}\n");
    }
    s += "6 0 1 2 3 4 5\n";
    let path = dir.join("l.ply");
    std::fs::write(&path, s).unwrap();
    let a = load(&path).unwrap();
    let areas = signed_area(&a.meshes[0], Vec3::Z);
    assert_eq!(areas.len(), 4);
    assert!(areas.iter().all(|&x| x > 0.0));
    assert!((areas.iter().sum::<f32>() - 3.0).abs() < 1e-5);
    assert!(
        a.meshes[0]
            .normals
            .iter()
            .all(|n| n.abs_diff_eq(Vec3::Z, 1e-6))
    );
    assert!(!a.warnings.is_empty());
}

// ---------------------------------------------------------------- bad input

fn expect_error(path: &Path, what: &str) -> String {
    let (outcome, _) = guarded_load(path);
    match outcome {
        Outcome::Failed(m) => {
            assert!(
                m.contains(&path.display().to_string()),
                "{what}: the message does not name the file: {m}"
            );
            m
        }
        Outcome::Loaded(_) => panic!("{what}: loaded"),
        Outcome::Panicked(m) => panic!("{what}: panicked: {m}"),
        Outcome::TimedOut => panic!("{what}: hung"),
    }
}

#[test]
fn bad_input_is_an_error_naming_the_file() {
    let dir_tmp = common::temp_dir("mesh-bad");
    let dir = dir_tmp.path().to_path_buf();
    let write = |name: &str, bytes: &[u8]| {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    // Deterministic pseudo-random garbage.
    let mut x = 0x2545F4914F6CDD1Du64;
    let garbage: Vec<u8> = (0..4096)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 24) as u8
        })
        .collect();
    for ext in ["gltf", "glb", "obj", "ply", "OBJ"] {
        expect_error(&write(&format!("empty.{ext}"), b""), "empty file");
        expect_error(
            &write(&format!("garbage.{ext}"), &garbage),
            "binary garbage",
        );
    }
    expect_error(&write("model.stl", b"solid x"), "unknown extension");
    expect_error(&dir.join("missing.obj"), "missing file");
    let d = dir.join("folder.gltf");
    std::fs::create_dir_all(&d).unwrap();
    expect_error(&d, "directory");

    // glTF: empty object, bad JSON, bad GLB headers, missing buffer, cycles, out-of-range
    // indices, non-finite positions, type mismatches.
    expect_error(&write("empty_object.gltf", b"{}"), "no asset");
    expect_error(
        &write("bad_json.gltf", b"{\"asset\": {\"version\": \"2.0\""),
        "bad JSON",
    );
    let mut glb = b"glTF".to_vec();
    glb.extend(2u32.to_le_bytes());
    glb.extend(10_000u32.to_le_bytes());
    glb.extend(b"\x10\0\0\0JSON{\"asset\":{}}");
    expect_error(&write("truncated.glb", &glb), "truncated GLB");
    let mut glb = b"glTF".to_vec();
    glb.extend(1u32.to_le_bytes());
    glb.extend(12u32.to_le_bytes());
    expect_error(&write("v1.glb", &glb), "GLB version 1");
    let tri = |extra: &str, accessors: &str, buffer: &str| {
        format!(
            "{{\"asset\":{{\"version\":\"2.0\"}},\"scene\":0,\"scenes\":[{{\"nodes\":[0]}}],\
             \"nodes\":[{{\"mesh\":0{extra}}}],\
             \"meshes\":[{{\"primitives\":[{{\"attributes\":{{\"POSITION\":0}},\"indices\":1}}]}}],\
             \"accessors\":{accessors},\
             \"bufferViews\":[{{\"buffer\":0,\"byteLength\":36}},\
             {{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6}}],\
             \"buffers\":[{{\"byteLength\":44,\"uri\":\"{buffer}\"}}]}}"
        )
    };
    let good_accessors = "[{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\",\
         \"min\":[0,0,0],\"max\":[1,1,0]},\
         {\"bufferView\":1,\"componentType\":5123,\"count\":3,\"type\":\"SCALAR\"}]";
    let bin = |coords: [f32; 9], idx: [u16; 3]| {
        let mut b: Vec<u8> = coords.iter().flat_map(|c| c.to_le_bytes()).collect();
        b.extend(idx.iter().flat_map(|i| i.to_le_bytes()));
        b.extend([0, 0]);
        b
    };
    let ok_coords = [0., 0., 0., 1., 0., 0., 0., 1., 0.];
    std::fs::write(dir.join("tri.bin"), bin(ok_coords, [0, 1, 2])).unwrap();
    let ok = write("tri.gltf", tri("", good_accessors, "tri.bin").as_bytes());
    let a = load(&ok).unwrap_or_else(|e| panic!("the well-formed triangle: {e}"));
    assert_eq!(a.triangle_count(), 1);
    let m = expect_error(
        &write(
            "no_bin.gltf",
            tri("", good_accessors, "nowhere.bin").as_bytes(),
        ),
        "missing buffer",
    );
    assert!(m.contains("buffers[0]"), "{m}");
    std::fs::write(dir.join("oob.bin"), bin(ok_coords, [0, 1, 3])).unwrap();
    let m = expect_error(
        &write("oob.gltf", tri("", good_accessors, "oob.bin").as_bytes()),
        "index out of range",
    );
    assert!(m.contains("meshes[0].primitives[0].indices"), "{m}");
    let mut nan = ok_coords;
    nan[4] = f32::NAN;
    std::fs::write(dir.join("nan.bin"), bin(nan, [0, 1, 2])).unwrap();
    let m = expect_error(
        &write("nan.gltf", tri("", good_accessors, "nan.bin").as_bytes()),
        "NaN position",
    );
    assert!(m.contains("attributes.POSITION"), "{m}");
    let m = expect_error(
        &write(
            "cycle.gltf",
            tri(",\"children\":[0]", good_accessors, "tri.bin").as_bytes(),
        ),
        "cycle",
    );
    assert!(m.contains("cycle"), "{m}");
    let vec2 = good_accessors.replacen("\"VEC3\"", "\"VEC2\"", 1);
    let m = expect_error(
        &write("vec2.gltf", tri("", &vec2, "tri.bin").as_bytes()),
        "VEC2 POSITION",
    );
    assert!(m.contains("VEC2"), "{m}");
    let long = good_accessors.replacen("\"count\":3", "\"count\":300", 1);
    let m = expect_error(
        &write("long.gltf", tri("", &long, "tri.bin").as_bytes()),
        "overlong accessor",
    );
    assert!(m.contains("accessors[0]"), "{m}");
    let float_idx = good_accessors.replacen("5123", "5126", 1);
    let m = expect_error(
        &write("fidx.gltf", tri("", &float_idx, "tri.bin").as_bytes()),
        "float indices",
    );
    assert!(m.contains("indices"), "{m}");

    // Truncated copies of a real GLB at several lengths.
    if let Some(assets) = assets_dir() {
        let glb = std::fs::read(assets.join("glTF/Box/glTF-Binary/Box.glb")).unwrap();
        for cut in [5, 12, 20, 100, glb.len() / 2, glb.len() - 1] {
            expect_error(
                &write(&format!("cut{cut}.glb"), &glb[..cut]),
                "truncated Box.glb",
            );
        }
    }

    // OBJ: line numbers in messages.
    let m = expect_error(
        &write("oob.obj", b"v 0 0 0\nv 1 0 0\n\nf 1 2 9\n"),
        "OBJ index",
    );
    assert!(m.contains("oob.obj:4:"), "{m}");
    let m = expect_error(&write("badnum.obj", b"v 0 0 0\nv 1 x 0\n"), "OBJ number");
    assert!(m.contains("badnum.obj:2:"), "{m}");
    let m = expect_error(
        &write("rel.obj", b"v 0 0 0\nf -1 -2 -3\n"),
        "OBJ relative index",
    );
    assert!(m.contains("rel.obj:2:"), "{m}");
    expect_error(&write("utf16.obj", b"\xFF\xFEv\x000\x00"), "UTF-16 OBJ");

    // PLY: out-of-range index (with its line), truncated binary, absurd counts.
    let mut ply = ply_ascii();
    let text = String::from_utf8(ply.clone())
        .unwrap()
        .replace("3 0 1 4", "3 0 1 5");
    ply = text.into_bytes();
    let m = expect_error(&write("oob.ply", &ply), "PLY index");
    assert!(m.contains("oob.ply:19:"), "{m}");
    let bin = ply_binary_le();
    for cut in [4, 60, bin.len() - 30, bin.len() - 3] {
        expect_error(
            &write(&format!("cut{cut}.ply"), &bin[..cut]),
            "truncated PLY",
        );
    }
    let huge = String::from_utf8_lossy(&ply_binary_le())
        .replace("element vertex 5", "element vertex 4000000000")
        .into_bytes();
    expect_error(&write("huge.ply", &huge), "huge PLY count");
    let noxyz = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float y\nend_header\n1\n";
    expect_error(&write("noxyz.ply", noxyz), "PLY without x");
}

#[test]
fn missing_mtl_and_textures_are_warnings() {
    let dir_tmp = common::temp_dir("mesh-mtl");
    let dir = dir_tmp.path().to_path_buf();
    std::fs::write(
        dir.join("m.mtl"),
        "newmtl red\nKd 1 0 0\nKs 0.5 0.5 0.5\nNs 64\nd 0.25\nNi 1.33\nmap_Kd -s 1 1 1 gone.png\n\
         newmtl short\nKd 0.5\nKa 1\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("m.obj"),
        "mtllib m.mtl\nmtllib absent.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n\
         usemtl red\nf 1 2 3\nusemtl short\nf 2 4 3\nusemtl nothing\nf 1 2 4\nl 1 2 3\n",
    )
    .unwrap();
    let a = load(&dir.join("m.obj")).unwrap();
    assert_eq!(a.triangle_count(), 3);
    let red = a.materials.iter().find(|m| m.name == "red").unwrap();
    assert_eq!(red.params.color, Vec3::new(1.0, 0.0, 0.0));
    assert_eq!(red.params.specular, Vec3::splat(0.5));
    assert_eq!(red.params.shininess, 64.0);
    assert!((red.params.transparency - 0.75).abs() < 1e-6);
    assert_eq!(red.params.ior, 1.33);
    assert_eq!(red.textures.base_color, None);
    let short = a.materials.iter().find(|m| m.name == "short").unwrap();
    assert_eq!(short.params.color, Vec3::splat(0.5));
    let all = a.warnings.join("\n");
    for needle in ["gone.png", "absent.mtl", "nothing", "line"] {
        assert!(all.contains(needle), "no warning about {needle}:\n{all}");
    }
}

#[test]
fn texture_sampling_is_bilinear_with_wrap_modes() {
    let texels = vec![
        Vec4::new(0.0, 0.0, 0.0, 1.0),
        Vec4::new(1.0, 0.0, 0.0, 1.0),
        Vec4::new(0.0, 1.0, 0.0, 1.0),
        Vec4::new(1.0, 1.0, 0.0, 1.0),
    ];
    let mut t = Texture {
        width: 2,
        height: 2,
        texels,
        wrap_u: Wrap::Repeat,
        wrap_v: Wrap::Repeat,
        name: "test".into(),
        srgb: false,
    };
    // Texel centres.
    assert_eq!(t.sample(Vec2::new(0.25, 0.25)), t.texels[0]);
    assert_eq!(t.sample(Vec2::new(0.75, 0.25)), t.texels[1]);
    assert_eq!(t.sample(Vec2::new(0.25, 0.75)), t.texels[2]);
    // Half-way between the two top texels.
    assert!(
        t.sample(Vec2::new(0.5, 0.25))
            .abs_diff_eq(Vec4::new(0.5, 0.0, 0.0, 1.0), 1e-6)
    );
    // Repeat: u = 0 is half-way between the last and first column.
    assert!(
        t.sample(Vec2::new(0.0, 0.25))
            .abs_diff_eq(Vec4::new(0.5, 0.0, 0.0, 1.0), 1e-6)
    );
    assert!(
        t.sample(Vec2::new(1.25, 0.25))
            .abs_diff_eq(t.texels[0], 1e-6)
    );
    t.wrap_u = Wrap::ClampToEdge;
    assert!(
        t.sample(Vec2::new(-3.0, 0.25))
            .abs_diff_eq(t.texels[0], 1e-6)
    );
    assert!(
        t.sample(Vec2::new(7.0, 0.25))
            .abs_diff_eq(t.texels[1], 1e-6)
    );
    t.wrap_u = Wrap::MirroredRepeat;
    assert!(
        t.sample(Vec2::new(1.25, 0.25))
            .abs_diff_eq(t.texels[1], 1e-6)
    );
    assert!(
        t.sample(Vec2::new(-0.25, 0.25))
            .abs_diff_eq(t.texels[0], 1e-6)
    );
    // Nothing panics on absurd coordinates.
    for uv in [
        Vec2::NAN,
        Vec2::INFINITY,
        Vec2::splat(-1e30),
        Vec2::splat(3e9),
    ] {
        let _ = t.sample(uv);
    }
    t.texels.clear();
    assert_eq!(t.sample(Vec2::ZERO), Vec4::ONE);
}

#[test]
fn big_models_load_in_reasonable_time() {
    let c = corpus();
    if c.assets.is_none() {
        return;
    }
    let mut times = HashMap::new();
    for rel in [
        "glTF/MetalRoughSpheresNoTextures/glTF/MetalRoughSpheresNoTextures.gltf",
        "glTF/ReciprocatingSaw/glTF/ReciprocatingSaw.gltf",
        "glTF/2CylinderEngine/glTF-Binary/2CylinderEngine.glb",
    ] {
        let path = c.assets.as_ref().unwrap().join(rel);
        let e = c.get(&path).unwrap();
        let a = c.asset(rel).unwrap();
        println!(
            "{rel}: {} triangles ({} unique) in {:.0} ms",
            a.triangle_count(),
            a.unique_triangle_count(),
            e.elapsed.as_secs_f64() * 1000.0
        );
        times.insert(rel, e.elapsed);
    }
    assert!(times.values().all(|t| *t < LOAD_LIMIT));
}

#[test]
fn error_type_is_usable() {
    // MeshError is a std error with a Display naming the file.
    let e: MeshError = load(Path::new("/nonexistent/x.glb")).unwrap_err();
    let boxed: Box<dyn std::error::Error + Send + Sync> = Box::new(e);
    assert!(boxed.to_string().contains("/nonexistent/x.glb"));
}

// ---------------------------------------------------------------- mutation fuzz

/// xorshift64*, deterministic.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545F4914F6CDD1D)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// One random corruption: flipped bytes, a cut, an insertion, a duplicated or deleted span,
/// or a character typical of the text formats dropped in.
fn mutate(rng: &mut Rng, data: &[u8]) -> Vec<u8> {
    let mut d = data.to_vec();
    if d.is_empty() {
        return vec![b'x'];
    }
    for _ in 0..1 + rng.below(3) {
        let at = rng.below(d.len());
        match rng.below(7) {
            0 => d[at] ^= 1 << rng.below(8),
            1 => d[at] = rng.next() as u8,
            2 => d.truncate(at.max(1)),
            3 => {
                let junk: Vec<u8> = (0..1 + rng.below(16)).map(|_| rng.next() as u8).collect();
                d.splice(at..at, junk);
            }
            4 => {
                let end = (at + 1 + rng.below(64)).min(d.len());
                let span = d[at..end].to_vec();
                d.splice(at..at, span);
            }
            5 => {
                let end = (at + 1 + rng.below(64)).min(d.len());
                d.drain(at..end);
            }
            _ => {
                const CHARS: &[u8] = b"-90/ \n.e+{}[],:\"1";
                d[at] = CHARS[rng.below(CHARS.len())];
            }
        }
        if d.is_empty() {
            d.push(b'0');
        }
    }
    d
}

/// A file to mutate: its name, its bytes, and a companion file (MTL, glTF buffer) that is
/// mutated instead about half of the time.
type Seed = (String, Vec<u8>, Option<(String, Vec<u8>)>);

#[test]
fn mutated_files_never_panic_or_hang() {
    let dir_tmp = common::temp_dir("mesh-fuzz");
    let dir = dir_tmp.path().to_path_buf();
    // (file name, bytes, companion file mutated instead when `true` is drawn)
    let mut seeds: Vec<Seed> = vec![
        ("a.ply".into(), ply_ascii(), None),
        ("le.ply".into(), ply_binary_le(), None),
        ("be.ply".into(), ply_binary_be(), None),
        (
            "m.obj".into(),
            b"mtllib m.mtl\no quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 1\n\
              vn 0 0 1\nusemtl red\nf 1/1/1 2/2/1 3/2/1 4/1/1\nf -1 -2 -3\ng tri\nf 1 2 3\n"
                .to_vec(),
            Some((
                "m.mtl".into(),
                b"newmtl red\nKd 1 0 0\nKs 0.2 0.2 0.2\nNs 20\nd 0.5\nmap_Kd -s 1 1 t.png\n"
                    .to_vec(),
            )),
        ),
    ];
    if let Some(assets) = assets_dir() {
        for rel in [
            "glTF/Box/glTF-Binary/Box.glb",
            "glTF/BoxTextured/glTF-Binary/BoxTextured.glb",
            "glTF/SimpleSparseAccessor/glTF/SimpleSparseAccessor.gltf",
            "glTF/TriangleWithoutIndices/glTF/TriangleWithoutIndices.gltf",
            "glTF/Cameras/glTF/Cameras.gltf",
        ] {
            let path = assets.join(rel);
            let bytes = std::fs::read(&path).unwrap();
            let companion = gltf::Gltf::open(&path)
                .ok()
                .and_then(|g| {
                    g.document.buffers().next().and_then(|b| match b.source() {
                        gltf::buffer::Source::Uri(u) => Some(u.to_string()),
                        _ => None,
                    })
                })
                .map(|u| {
                    (
                        u.clone(),
                        std::fs::read(path.parent().unwrap().join(&u)).unwrap(),
                    )
                });
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            seeds.push((name, bytes, companion));
        }
    }
    // HYTRACE_FUZZ_ROUNDS raises the number of mutations per seed file for a longer run.
    let rounds: usize = std::env::var("HYTRACE_FUZZ_ROUNDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(120);
    let mut rng = Rng(std::env::var("HYTRACE_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0x9E3779B97F4A7C15));
    let mut loads = 0;
    let mut problems = Vec::new();
    let start = Instant::now();
    for (name, bytes, companion) in &seeds {
        let path = dir.join(name);
        for _ in 0..rounds {
            let (main, side) = match companion {
                Some((cname, cbytes)) if rng.below(2) == 0 => {
                    (bytes.clone(), Some((cname, mutate(&mut rng, cbytes))))
                }
                Some((cname, cbytes)) => (mutate(&mut rng, bytes), Some((cname, cbytes.clone()))),
                None => (mutate(&mut rng, bytes), None),
            };
            std::fs::write(&path, &main).unwrap();
            if let Some((cname, cbytes)) = &side {
                std::fs::write(dir.join(cname), cbytes).unwrap();
            }
            loads += 1;
            match guarded_load(&path).0 {
                Outcome::Loaded(a) => check_invariants(name, &a, &mut problems),
                Outcome::Failed(m) => {
                    if !m.contains(&path.display().to_string()) {
                        problems.push(format!("{name}: the error does not name the file: {m}"));
                    }
                }
                Outcome::Panicked(m) => {
                    let keep = dir.join(format!("panic-{loads}-{name}"));
                    let _ = std::fs::write(&keep, &main);
                    problems.push(format!(
                        "{name}: panicked ({m}); input kept as {}",
                        keep.display()
                    ));
                }
                Outcome::TimedOut => problems.push(format!("{name}: hung")),
            }
        }
    }
    println!(
        "{loads} mutated files loaded in {:.1} s",
        start.elapsed().as_secs_f64()
    );
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// A mesh file, a glTF buffer or a material library that leads to a device is refused
/// before anything is read: read to its end, `/dev/zero` took memory until the system
/// refused (4 GB and more).
#[cfg(unix)]
#[test]
fn devices_are_refused_as_mesh_files_and_buffers() {
    let dir = tempfile::tempdir().unwrap();
    let link = |name: &str| {
        let p = dir.path().join(name);
        std::os::unix::fs::symlink("/dev/zero", &p).unwrap();
        p
    };
    for name in ["zero.obj", "zero.ply", "zero.glb", "zero.gltf"] {
        let e = load(&link(name)).unwrap_err().to_string();
        assert!(e.contains(name) && e.contains("not a regular file"), "{e}");
    }
    link("zero.bin");
    let gltf = dir.path().join("buffer.gltf");
    std::fs::write(
        &gltf,
        r#"{"asset":{"version":"2.0"},"buffers":[{"uri":"zero.bin","byteLength":36}]}"#,
    )
    .unwrap();
    let e = load(&gltf).unwrap_err().to_string();
    assert!(
        e.contains("zero.bin") && e.contains("not a regular file"),
        "{e}"
    );
    link("zero.mtl");
    let obj = dir.path().join("library.obj");
    std::fs::write(
        &obj,
        "mtllib zero.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    )
    .unwrap();
    let a = load(&obj).unwrap();
    assert!(
        a.warnings
            .iter()
            .any(|w| w.contains("zero.mtl") && w.contains("not a regular file")),
        "{:?}",
        a.warnings
    );
}

/// A glTF primitive without NORMAL gets flat normals (glTF 2.0 §3.7.2.1: clients MUST
/// calculate flat normals): two triangles folded along a shared edge keep their own face
/// normals, +Z and +Y, not an average across the fold.
#[test]
fn gltf_without_normals_is_flat_shaded() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fold.gltf");
    std::fs::write(
        &path,
        r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],
        "meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1}]}],
        "buffers":[{"byteLength":60,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAAAAAAAAAAAAIA/AAABAAIAAQAAAAMA"}],
        "bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":48},{"buffer":0,"byteOffset":48,"byteLength":12}],
        "accessors":[{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,1]},
                     {"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR"}]}"#,
    )
    .unwrap();
    let a = load(&path).unwrap();
    assert_eq!(a.triangle_count(), 2);
    let m = &a.meshes[0];
    for (t, face) in m.triangles.iter().zip([Vec3::Z, Vec3::Y]) {
        for &v in t {
            let n = m.normals[v as usize];
            assert!((n - face).length() < 1e-6, "normal {n} of a face {face}");
        }
        let [p, q, r] = t.map(|v| m.positions[v as usize]);
        assert!(
            (q - p).cross(r - p).normalize().dot(face) > 0.999,
            "winding kept"
        );
    }
}

/// A glTF 1.0 document (its `scenes` a map, not a list) is named for what it is, as a GLB of
/// version 1 is, not reported as a schema error about its scenes.
#[test]
fn gltf_1_documents_are_named_as_such() {
    let Some(assimp) = assimp_dir() else { return };
    let path = assimp.join("glTF/BoxTextured-glTF/BoxTextured.gltf");
    let e = load(&path).unwrap_err().to_string();
    assert!(e.contains("glTF version 1.0 is not supported"), "{e}");
}

/// A one-triangle glTF whose JSON `edit` changes (a `data:` buffer of three float positions).
fn triangle_gltf(dir: &Path, edit: impl FnOnce(&mut serde_json::Value)) -> PathBuf {
    let mut doc = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}]
    });
    edit(&mut doc);
    let path = dir.join("triangle.gltf");
    std::fs::write(&path, doc.to_string()).unwrap();
    path
}

/// glTF 2.0's MUSTs the loader holds a file to, each refused with the place it is broken:
/// the major version, POSITION's float components (integers only with KHR_mesh_quantization),
/// buffer views inside their buffer's byteLength; a camera with an impossible field of view is
/// skipped with a warning.
#[test]
fn gltf_files_breaking_the_specification_are_refused_by_place() {
    let dir = tempfile::tempdir().unwrap();
    let error = |edit: &dyn Fn(&mut serde_json::Value)| {
        load(&triangle_gltf(dir.path(), edit))
            .unwrap_err()
            .to_string()
    };
    assert_eq!(
        load(&triangle_gltf(dir.path(), |_| {}))
            .unwrap()
            .triangle_count(),
        1
    );

    let e = error(&|d| d["asset"]["version"] = "3.0".into());
    assert!(
        e.contains("asset.version: glTF version 3.0 is not supported"),
        "{e}"
    );
    let e = error(&|d| d["asset"]["minVersion"] = "2.1".into());
    assert!(e.contains("asset.minVersion"), "{e}");

    let e = error(&|d| d["accessors"][0]["componentType"] = 5121.into());
    assert!(
        e.contains("attributes.POSITION") && e.contains("UNSIGNED_BYTE") && e.contains("FLOAT"),
        "{e}"
    );
    // the same bytes read as quantized positions, where the file says it uses them
    let quantized = triangle_gltf(dir.path(), |d| {
        d["accessors"][0]["componentType"] = 5121.into();
        d["extensionsUsed"] = serde_json::json!(["KHR_mesh_quantization"]);
    });
    assert!(load(&quantized).is_ok());

    let e = error(&|d| d["buffers"][0]["byteLength"] = 10.into());
    assert!(
        e.contains("bufferViews[0]") && e.contains("byteLength is 10"),
        "{e}"
    );

    for camera in [
        serde_json::json!({"type": "perspective", "perspective": {"yfov": 0.0, "znear": 0.1}}),
        serde_json::json!({"type": "perspective", "perspective": {"yfov": 1000.0, "znear": 0.1}}),
        serde_json::json!({"type": "perspective",
                           "perspective": {"yfov": 0.8, "aspectRatio": 0.0, "znear": 0.1}}),
        serde_json::json!({"type": "orthographic",
                           "orthographic": {"xmag": 0.0, "ymag": 1.0, "znear": 0.0, "zfar": 1.0}}),
    ] {
        let path = triangle_gltf(dir.path(), |d| {
            d["nodes"] = serde_json::json!([{"mesh": 0, "camera": 0}]);
            d["cameras"] = serde_json::json!([camera]);
        });
        let a = load(&path).unwrap();
        assert!(a.cameras.is_empty(), "{camera} kept");
        assert!(
            a.warnings
                .iter()
                .any(|w| w.contains("cameras[0]") && w.contains("skipped")),
            "{camera}: {:?}",
            a.warnings
        );
    }
}
