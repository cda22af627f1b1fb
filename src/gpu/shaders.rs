//! The WGSL sources: the generated prelude (constants, structs, bindings shared with Rust) and
//! the shader files of `shaders/`, assembled into modules.

use super::layout::{WgslStruct, WgslType};
use super::records::*;
use crate::accel::field;
use crate::scene::Shadow;
use crate::scene::file::NormalMethod;
use crate::scene::material::MaterialParams;
use crate::scene::mesh::Wrap;
use crate::sdf::simplify::Verdict;
use crate::sdf::tape;

/// The tape interpreter (`Tape::eval_in`, `Tape::eval_material`).
pub const TAPE_WGSL: &str = include_str!("../../shaders/tape.wgsl");
/// An object's field octree: point location and the ray walk (`src/accel/field.rs`).
pub const FIELD_WGSL: &str = include_str!("../../shaders/field.wgsl");
/// Sphere tracing, normals, penumbrae, exits (`src/trace/sphere.rs`, `src/trace/normal.rs`).
pub const SDF_WGSL: &str = include_str!("../../shaders/sdf.wgsl");
/// The wide BVH walk over the CPU's own trees and the watertight triangle test (`src/accel`).
pub const MESH_WGSL: &str = include_str!("../../shaders/mesh.wgsl");
/// The hybrid scene queries (`SceneTracer`).
pub const SCENE_WGSL: &str = include_str!("../../shaders/scene.wgsl");
/// A compute kernel over the scene library: its file and entry point, and its group 1 (an
/// input array, an output array, the chunk parameters), declared for WGSL and for the host
/// from one list ([`KernelSource::io`]).
#[derive(Debug, Clone, Copy)]
pub struct KernelSource {
    /// File name under `shaders/`.
    pub file: &'static str,
    /// Its text.
    pub wgsl: &'static str,
    /// The `@compute` entry point.
    pub entry: &'static str,
    /// (name, WGSL element type) of the input and of the output array.
    pub input: (&'static str, fn() -> String),
    /// See [`KernelSource::input`].
    pub output: (&'static str, fn() -> String),
}

impl KernelSource {
    /// Group 1: the input, the output, `chunk`.
    pub fn io(&self) -> Bindings {
        vec![
            (
                self.input.0,
                BindingKind::Storage,
                format!("array<{}>", (self.input.1)()),
            ),
            (
                self.output.0,
                BindingKind::StorageReadWrite,
                format!("array<{}>", (self.output.1)()),
            ),
            ("chunk", BindingKind::Uniform, ChunkParams::wgsl_name()),
        ]
    }

    /// The whole module: the scene library, group 1, the kernel.
    pub fn module(&self) -> String {
        with_kernel(&(bindings_wgsl(1, &self.io()) + self.wgsl))
    }
}

/// The batch query kernel ([`crate::gpu::query::GpuQuery`]).
pub const QUERY_KERNEL: KernelSource = KernelSource {
    file: "query.wgsl",
    wgsl: include_str!("../../shaders/query.wgsl"),
    entry: "query_main",
    input: ("query_rays", QueryRay::wgsl_name),
    output: ("query_results", QueryResult::wgsl_name),
};
/// The tape evaluation kernel ([`crate::gpu::query::GpuSdfEvaluator`]).
pub const EVAL_KERNEL: KernelSource = KernelSource {
    file: "eval.wgsl",
    wgsl: include_str!("../../shaders/eval.wgsl"),
    entry: "eval_main",
    input: ("eval_points", <[f32; 4]>::wgsl_name),
    output: ("eval_values", f32::wgsl_name),
};
/// The probe kernel: shading's scene queries per ray, for tests against the CPU.
pub const PROBE_KERNEL: KernelSource = KernelSource {
    file: "probe.wgsl",
    wgsl: include_str!("../../shaders/probe.wgsl"),
    entry: "probe_main",
    input: ("probe_rays", QueryRay::wgsl_name),
    output: ("probe_results", ProbeResult::wgsl_name),
};
/// The field probe kernel: point location and the octree walk per ray, for tests against the
/// CPU.
pub const FIELD_PROBE_KERNEL: KernelSource = KernelSource {
    file: "field_probe.wgsl",
    wgsl: include_str!("../../shaders/field_probe.wgsl"),
    entry: "field_probe_main",
    input: ("field_probe_rays", QueryRay::wgsl_name),
    output: ("field_probe_results", FieldProbeResult::wgsl_name),
};

/// Threads per workgroup of the compute kernels (1-D).
pub const WORKGROUP_SIZE: u32 = 64;

/// `SceneHit.kind` / `QueryResult.kind`: nothing hit.
pub const HIT_MISS: u32 = 0;
/// An SDF object was hit.
pub const HIT_SDF: u32 = 1;
/// A mesh instance was hit.
pub const HIT_MESH: u32 = 2;

/// `ChunkParams.queries` bit of the query kernel: compute the closest hit.
pub const QUERY_CLOSEST: u32 = 1;
/// `ChunkParams.queries` bit of the query kernel: compute occlusion.
pub const QUERY_OCCLUDED: u32 = 2;

/// The number a shadow kind has in WGSL (`SHADOW_*`) and its sharpness k.
pub fn shadow_code(shadow: Shadow) -> (u32, f32) {
    match shadow {
        Shadow::None => (0, 0.0),
        Shadow::Hard => (1, 0.0),
        Shadow::Soft(k) => (2, k),
        Shadow::SoftImproved(k) => (3, k),
    }
}

/// The number a normal estimator has in WGSL (`NORMALS_*`).
pub fn normals_code(method: NormalMethod) -> u32 {
    match method {
        NormalMethod::Central => 0,
        NormalMethod::Tetrahedral => 1,
    }
}

/// The number a leaf verdict has in WGSL (`VERDICT_*`).
pub fn verdict_code(verdict: Verdict) -> u32 {
    match verdict {
        Verdict::Empty => 0,
        Verdict::Full => 1,
        Verdict::Surface => 2,
    }
}

/// The number a texture wrap mode has in WGSL (`WRAP_*`).
pub fn wrap_code(wrap: Wrap) -> u32 {
    match wrap {
        Wrap::Repeat => 0,
        Wrap::ClampToEdge => 1,
        Wrap::MirroredRepeat => 2,
    }
}

/// How a buffer is bound.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BindingKind {
    /// `var<uniform>`.
    Uniform,
    /// `var<storage, read>`.
    Storage,
    /// `var<storage, read_write>`.
    StorageReadWrite,
}

/// A bind group's buffers in binding order: (WGSL name, kind, WGSL type). The WGSL
/// declarations ([`bindings_wgsl`]) and the host's layout ([`layout_entries`]) are both made
/// from one such list, so binding numbers are never written by hand.
pub type Bindings = Vec<(&'static str, BindingKind, String)>;

/// The WGSL declarations of `bindings` as group `group`.
pub fn bindings_wgsl(group: u32, bindings: &Bindings) -> String {
    let mut s = String::new();
    for (i, (name, kind, ty)) in bindings.iter().enumerate() {
        let space = match kind {
            BindingKind::Uniform => "uniform",
            BindingKind::Storage => "storage, read",
            BindingKind::StorageReadWrite => "storage, read_write",
        };
        s += &format!("@group({group}) @binding({i}) var<{space}> {name}: {ty};\n");
    }
    s
}

/// The compute-stage layout entries of `bindings`, numbered as [`bindings_wgsl`] numbers them.
pub fn layout_entries(bindings: &Bindings) -> Vec<wgpu::BindGroupLayoutEntry> {
    bindings
        .iter()
        .enumerate()
        .map(|(i, (_, kind, _))| wgpu::BindGroupLayoutEntry {
            binding: i as u32,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: match kind {
                    BindingKind::Uniform => wgpu::BufferBindingType::Uniform,
                    BindingKind::Storage => wgpu::BufferBindingType::Storage { read_only: true },
                    BindingKind::StorageReadWrite => {
                        wgpu::BufferBindingType::Storage { read_only: false }
                    }
                },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        })
        .collect()
}

/// A bind group of `buffers`, given in the order of the list `layout` was made from.
pub fn bind_buffers(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::BindGroupLayout,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout,
        entries: &entries,
    })
}

/// The scene buffers of bind group 0 in binding order: (name, kind, WGSL type). The host
/// creates its buffers in this order ([`crate::gpu::scene::GpuScene`]) and the prelude
/// declares them from the same list.
pub fn scene_bindings() -> Bindings {
    use BindingKind::*;
    let array = |t: String| format!("array<{t}>");
    vec![
        ("globals", Uniform, SceneGlobals::wgsl_name()),
        ("instrs", Storage, array(InstrRecord::wgsl_name())),
        ("objects", Storage, array(SdfObjectRecord::wgsl_name())),
        ("field_nodes", Storage, array(u32::wgsl_name())),
        ("field_leaves", Storage, array(FieldLeafRecord::wgsl_name())),
        ("field_tapes", Storage, array(TapeRef::wgsl_name())),
        ("nodes", Storage, array(WideNodeRecord::wgsl_name())),
        ("refs", Storage, array(u32::wgsl_name())),
        ("tri_blocks", Storage, array(TriBlockRecord::wgsl_name())),
        ("meshes", Storage, array(MeshRecord::wgsl_name())),
        ("vertices", Storage, array(VertexRecord::wgsl_name())),
        (
            "triangle_indices",
            Storage,
            array(TriangleIndices::wgsl_name()),
        ),
        ("instances", Storage, array(InstanceRecord::wgsl_name())),
        ("materials", Storage, array(MaterialRecord::wgsl_name())),
        ("textures", Storage, array(TextureRecord::wgsl_name())),
        ("texels", Storage, array(u32::wgsl_name())),
    ]
}

/// The WGSL `Material` struct (the fields of [`MaterialParams`]), the lanes' type
/// `MaterialLanes` (`MATERIAL_FLOATS` floats as vec4s) and `material_from_lanes`, which reads a
/// `Material` from them. Which lane holds which field is found by packing a probe material
/// with [`MaterialParams::to_vec`], so the packing is defined once.
fn material_wgsl() -> String {
    let probe = MaterialParams::numbered();
    let lanes = probe.to_vec();
    let lane = |marker: f32| -> String {
        let i = lanes
            .iter()
            .position(|&l| l == marker)
            .expect("every field of MaterialParams has a lane");
        format!("l[{}][{}]", i / 4, i % 4)
    };
    let fields: [(&str, &[f32]); 13] = [
        ("color", &[1.0, 2.0, 3.0]),
        ("diffuse", &[4.0]),
        ("specular", &[5.0, 6.0, 7.0]),
        ("shininess", &[8.0]),
        ("reflectivity", &[9.0]),
        ("transparency", &[10.0]),
        ("ior", &[11.0]),
        ("pbr", &[12.0]),
        ("metallic", &[13.0]),
        ("roughness", &[14.0]),
        ("emissive", &[15.0, 16.0, 17.0]),
        ("occlusion", &[18.0]),
        ("opacity", &[19.0]),
    ];
    let vecs = tape::MATERIAL_FLOATS.div_ceil(4);
    let mut s = format!(
        "const MATERIAL_VECS: u32 = {vecs}u;\nalias MaterialLanes = array<vec4<f32>, {vecs}>;\n\n"
    );
    s += "struct Material {\n";
    for (name, markers) in &fields {
        let ty = if markers.len() == 3 {
            "vec3<f32>"
        } else {
            "f32"
        };
        s += &format!("    {name}: {ty},\n");
    }
    s += "}\n\nfn material_from_lanes(l: MaterialLanes) -> Material {\n    return Material(\n";
    for (name, markers) in &fields {
        let parts: Vec<String> = markers.iter().map(|&m| lane(m)).collect();
        if parts.len() == 3 {
            s += &format!("        vec3<f32>({}), // {name}\n", parts.join(", "));
        } else {
            s += &format!("        {}, // {name}\n", parts[0]);
        }
    }
    s += "    );\n}\n\n";
    // the inverse, for the probe kernel's read-back
    s += "fn lanes_from_material(m: Material) -> MaterialLanes {\n    var l: MaterialLanes;\n";
    for (name, markers) in &fields {
        for (k, &m) in markers.iter().enumerate() {
            let component = if markers.len() == 3 {
                format!("m.{name}.{}", ["x", "y", "z"][k])
            } else {
                format!("m.{name}")
            };
            s += &format!("    {} = {component};\n", lane(m));
        }
    }
    s += "    return l;\n}\n";
    s
}

/// Everything the shader files share with Rust, generated: tape opcodes and limits, the
/// buffer structs, the enumerations' numbers, `Material`, and the scene bindings (group 0).
pub fn wgsl_prelude() -> String {
    let mut s = String::from("// ---- generated by hytrace::gpu::shaders::wgsl_prelude ----\n");
    s += &tape::wgsl_constants();
    let u = |name: &str, v: u32| format!("const {name}: u32 = {v}u;\n");
    s += &u("NONE", NONE);
    s += &u("STACK_SIZE", STACK_SIZE);
    // the wide BVH's child encoding and node-test widening (crate::accel::bvh)
    s += &u("LEAF_BIT", crate::accel::bvh::LEAF_BIT);
    s += &u("FIRST_MASK", crate::accel::bvh::FIRST_MASK);
    s += &format!("const WIDEN: f32 = {:?};\n", crate::accel::bvh::WIDEN);
    // the normal's finite-difference step (crate::trace::normal::step_for)
    let f = |name: &str, v: f32| format!("const {name}: f32 = {v:?};\n");
    s += &f("NORMAL_STEP_FLOOR", crate::trace::normal::STEP_FLOOR);
    s += &f("NORMAL_RELATIVE_STEP", crate::trace::normal::RELATIVE_STEP);
    s += &u("WORKGROUP_SIZE", WORKGROUP_SIZE);
    s += &u("HIT_MISS", HIT_MISS);
    s += &u("HIT_SDF", HIT_SDF);
    s += &u("HIT_MESH", HIT_MESH);
    s += &u("QUERY_CLOSEST", QUERY_CLOSEST);
    s += &u("QUERY_OCCLUDED", QUERY_OCCLUDED);
    s += &u("SHADOW_NONE", shadow_code(Shadow::None).0);
    s += &u("SHADOW_HARD", shadow_code(Shadow::Hard).0);
    s += &u("SHADOW_SOFT", shadow_code(Shadow::Soft(1.0)).0);
    s += &u(
        "SHADOW_SOFT_IMPROVED",
        shadow_code(Shadow::SoftImproved(1.0)).0,
    );
    s += &u("NORMALS_CENTRAL", normals_code(NormalMethod::Central));
    s += &u(
        "NORMALS_TETRAHEDRAL",
        normals_code(NormalMethod::Tetrahedral),
    );
    s += &u("WRAP_REPEAT", wrap_code(Wrap::Repeat));
    s += &u("WRAP_CLAMP_TO_EDGE", wrap_code(Wrap::ClampToEdge));
    s += &u("WRAP_MIRRORED_REPEAT", wrap_code(Wrap::MirroredRepeat));
    s += &u("TEXELS_PACKED8", crate::gpu::records::TEXELS_PACKED8);
    s += &u("TEXELS_SRGB", crate::gpu::records::TEXELS_SRGB);
    s += &u("ALPHA_OPAQUE", crate::gpu::records::ALPHA_OPAQUE);
    s += &u("ALPHA_MASK", crate::gpu::records::ALPHA_MASK);
    s += &u("ALPHA_BLEND", crate::gpu::records::ALPHA_BLEND);
    s += &u("VERDICT_EMPTY", verdict_code(Verdict::Empty));
    s += &u("VERDICT_FULL", verdict_code(Verdict::Full));
    s += &u("VERDICT_SURFACE", verdict_code(Verdict::Surface));
    s += &u("FIELD_MAX_DEPTH", field::MAX_DEPTH);
    s += &u("FIELD_LEAF", field::LEAF);
    s += &u("FIELD_PROBE_LEAVES", FIELD_PROBE_LEAVES);
    s += &u("MAX_SKIPS", crate::trace::step::MAX_SKIPS);
    // the shortest decimal that reads back as the same f32
    let f = |name: &str, v: f32| format!("const {name}: f32 = {v:?}f;\n");
    s += &f("TINY_DIRECTION", field::TINY_DIRECTION);
    s += &f("FALL_ROUNDING", field::FALL_ROUNDING);
    s += &f("HART_STEP_MARGIN", crate::trace::sphere::HART_STEP_MARGIN);
    s += "\n";
    for decl in [
        InstrRecord::wgsl(),
        TapeRef::wgsl(),
        SdfObjectRecord::wgsl(),
        FieldLeafRecord::wgsl(),
        WideNodeRecord::wgsl(),
        TriBlockRecord::wgsl(),
        MeshRecord::wgsl(),
        VertexRecord::wgsl(),
        TriangleIndices::wgsl(),
        InstanceRecord::wgsl(),
        MaterialRecord::wgsl(),
        TextureRecord::wgsl(),
        SceneGlobals::wgsl(),
        QueryRay::wgsl(),
        QueryResult::wgsl(),
        ChunkParams::wgsl(),
        ProbeResult::wgsl(),
        FieldProbeResult::wgsl(),
    ] {
        s += &decl;
    }
    s += &material_wgsl();
    s += "\n";
    s += &bindings_wgsl(0, &scene_bindings());
    s += "// ---- end of generated prelude ----\n\n";
    s
}

/// The scene library: prelude, tape interpreter, field octrees, mesh traversal, sphere
/// tracing and the hybrid queries of `scene.wgsl` (the functions shading builds on). Kernels
/// are appended to it.
pub fn scene_library() -> String {
    let mut s = wgsl_prelude();
    for part in [TAPE_WGSL, FIELD_WGSL, MESH_WGSL, SDF_WGSL, SCENE_WGSL] {
        s += part;
        s += "\n";
    }
    s
}

/// The library followed by a kernel source (a `@compute` entry point, after the declarations
/// of its other bind groups: [`KernelSource::module`], `gpu::render::render_shader_source`).
pub fn with_kernel(kernel: &str) -> String {
    scene_library() + kernel
}

/// Every shader module the crate builds, by name (validated with naga in the tests).
pub fn all_modules() -> Vec<(&'static str, String)> {
    [QUERY_KERNEL, EVAL_KERNEL, PROBE_KERNEL, FIELD_PROBE_KERNEL]
        .iter()
        .map(|k| (k.file, k.module()))
        .collect()
}

/// Parses and validates a WGSL module with naga (no adapter needed), panicking with the
/// compiler's message: the check every shader the crate builds passes in the tests.
#[cfg(test)]
pub(crate) fn validate(name: &str, src: &str) -> naga::Module {
    let module = naga::front::wgsl::parse_str(src)
        .unwrap_or_else(|e| panic!("{name} does not parse:\n{}", e.emit_to_string(src)));
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default(),
    )
    .validate(&module)
    .unwrap_or_else(|e| panic!("{name} does not validate:\n{}", e.emit_to_string(src)));
    module
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every file of `shaders/` with the prelude and the files it builds on, and every
    /// module the crate compiles, parse and validate with naga (no adapter needed).
    #[test]
    fn every_shader_parses_and_validates() {
        let mut src = wgsl_prelude();
        validate("the prelude", &src);
        for (name, part) in [
            ("tape.wgsl", TAPE_WGSL),
            ("field.wgsl", FIELD_WGSL),
            ("mesh.wgsl", MESH_WGSL),
            ("sdf.wgsl", SDF_WGSL),
            ("scene.wgsl", SCENE_WGSL),
        ] {
            src += part;
            validate(name, &src);
        }
        for (name, module) in all_modules() {
            validate(name, &module);
        }
    }

    #[test]
    fn the_prelude_declares_every_opcode_and_binding_once() {
        let p = wgsl_prelude();
        for op in crate::sdf::tape::Op::ALL {
            let decl = format!(
                "const OP_{}: u32 = {}u;",
                op.name().to_uppercase(),
                *op as u32
            );
            assert_eq!(p.matches(&decl).count(), 1, "{decl}");
        }
        for (i, (name, _, _)) in scene_bindings().iter().enumerate() {
            assert!(
                p.contains(&format!("@group(0) @binding({i}) var<")) && p.contains(name),
                "binding {i} `{name}`"
            );
        }
    }

    #[test]
    fn material_lanes_follow_the_rust_packing() {
        let m = material_wgsl();
        // MaterialParams::to_vec puts colour in lanes 0–2 and the ior in lane 10
        assert!(
            m.contains("vec3<f32>(l[0][0], l[0][1], l[0][2]), // color"),
            "{m}"
        );
        assert!(m.contains("l[2][2], // ior"), "{m}");
        assert!(m.contains("l[4][2], // opacity"), "{m}");
        assert!(m.contains("l[3][2] = m.emissive.x;"), "{m}");
    }
}
