//! The records of the GPU buffers: one Rust declaration each, from which the WGSL structs are
//! generated (see [`crate::gpu::layout`]).

use crate::gpu_struct;

/// `MaterialRecord::alpha_mode` of `AlphaMode::Opaque` (and of scene materials).
pub const ALPHA_OPAQUE: u32 = 0;
/// `MaterialRecord::alpha_mode` of `AlphaMode::Mask`.
pub const ALPHA_MASK: u32 = 1;
/// `MaterialRecord::alpha_mode` of `AlphaMode::Blend`.
pub const ALPHA_BLEND: u32 = 2;

/// `TextureRecord::wrap` bit: one `u32` per texel, RGBA bytes from the lowest
/// (`Texture::packed8`); without it, four (the f32 bits of R, G, B, A).
pub const TEXELS_PACKED8: u32 = 1 << 8;
/// `TextureRecord::wrap` bit: packed colour bytes are sRGB-encoded (decoded on sampling).
pub const TEXELS_SRGB: u32 = 1 << 9;

/// "No such node / tape register / override": a sentinel index.
pub const NONE: u32 = u32::MAX;

/// Entries of each fixed-size traversal stack in `mesh.wgsl` and `scene.wgsl`. A visited wide
/// node replaces its own entry by up to eight children, so a tree of D levels needs at most
/// 7·D + 1 entries: up to 18 levels fit, and deeper trees are refused at upload time (see
/// [`crate::gpu::scene`]).
pub const STACK_SIZE: u32 = 128;

gpu_struct! {
    /// Where one tape lives in the shared instruction buffer.
    pub struct TapeRef(16) {
        /// First instruction.
        pub start: u32,
        /// Instruction count.
        pub len: u32,
        /// Register holding the distance at the end.
        pub result: u32,
        /// Material register holding the blended material at the end (shading tapes), or
        /// [`NONE`].
        pub material: u32,
    }
}

gpu_struct! {
    /// One tape instruction as the GPU reads it: the bytes of [`crate::sdf::tape::Instr`],
    /// whose first word holds the operation and register bytes (at the bit positions
    /// `INSTR_*_SHIFT` that `sdf::tape::wgsl_constants` generates from `Instr`) and whose
    /// second is the immediate.
    pub struct InstrRecord(8) {
        /// Operation, destination and operand registers, a byte each.
        pub code: u32,
        /// Immediate bits (a float, a register or a material number).
        pub imm: u32,
    }
}

// The GPU buffer is the tape's instructions reinterpreted: same size, same bytes.
const _: () =
    assert!(std::mem::size_of::<InstrRecord>() == std::mem::size_of::<crate::sdf::tape::Instr>());
const _: () = assert!(std::mem::offset_of!(InstrRecord, imm) == crate::sdf::tape::INSTR_IMM_OFFSET);

/// The GPU view of a tape's instructions (a copy of the same bytes).
pub fn instr_records(instrs: &[crate::sdf::tape::Instr]) -> &[InstrRecord] {
    bytemuck::cast_slice(instrs)
}

gpu_struct! {
    /// One SDF object: world bounds, its field octree and its two whole tapes.
    pub struct SdfObjectRecord(144) {
        /// Bounds minimum (infinite coordinates stored as ∓`f32::MAX`).
        pub lo: [f32; 3],
        /// 1 when the bounds are NaN (unknown: the whole ray is visited), else 0.
        pub nan_bounds: u32,
        /// Bounds maximum.
        pub hi: [f32; 3],
        /// Index in the field node buffer of the octree's root, or [`NONE`] without one.
        pub field_root: u32,
        /// Minimum of the box the octree covers (`FieldOctree::bounds`).
        pub field_lo: [f32; 3],
        /// 1 when the gradient enclosure outside the octree (`ObjectField::outside`) is
        /// known, 0 for the whole line.
        pub outside_graded: u32,
        /// Maximum of the box the octree covers.
        pub field_hi: [f32; 3],
        /// 1 for a convex field (`ObjectField::convex`), whose marches end early
        /// (`sphere::ConvexBound`), else 0.
        pub convex: u32,
        /// Lower ends of the gradient enclosure outside the octree (zeros when
        /// `outside_graded` is 0).
        pub outside_lo: [f32; 3],
        /// A convex field's rounding model: error per unit of magnitude
        /// (`RoundingModel::relative`).
        pub convex_relative: f32,
        /// Upper ends of the gradient enclosure outside the octree.
        pub outside_hi: [f32; 3],
        /// A convex field's rounding model: 1 + its largest constant (`RoundingModel::scale`).
        pub convex_scale: f32,
        /// The whole distance tape (outside the octree's box, or without one).
        pub distance: TapeRef,
        /// The whole shading tape (distance and blended material).
        pub shading: TapeRef,
        /// 1 when Hart's march takes the whole tape rather than the octree's leaves
        /// (`FieldOctree::marched_whole`), else 0.
        pub marched_whole: u32,
        /// Unused (the record's size is a multiple of 16 bytes).
        pub reserved0: u32,
        /// Unused.
        pub reserved1: u32,
        /// Unused.
        pub reserved2: u32,
    }
}

gpu_struct! {
    /// One leaf of an object's field octree (`accel::field::Leaf`). The field node buffer
    /// holds every object's `FieldOctree::raw_nodes`, rebased: an inner node is the index in
    /// that buffer of its first child, a leaf is `FIELD_LEAF` | an index into the leaf buffer.
    pub struct FieldLeafRecord(48) {
        /// Lower ends of the enclosures of ∂f/∂x, ∂f/∂y, ∂f/∂z over the box (`Leaf::gradient`;
        /// zeros when `graded` is 0).
        pub gradient_lo: [f32; 3],
        /// Index into the field tape buffer: the leaf's distance tape.
        pub tape: u32,
        /// Upper ends of the gradient enclosures.
        pub gradient_hi: [f32; 3],
        /// Index into the field tape buffer: the leaf's shading tape.
        pub shading: u32,
        /// What the box holds (`VERDICT_*`).
        pub verdict: u32,
        /// A lower bound on f over the box.
        pub min_value: f32,
        /// 1 when the gradient enclosure is known (finite), 0 for the whole line: WGSL has no
        /// infinities to mark it as the CPU does.
        pub graded: u32,
        /// Padding to WGSL's 16-byte struct alignment.
        pub pad: u32,
    }
}

gpu_struct! {
    /// A node of a wide BVH exactly as the CPU walks it (`crate::accel::bvh::WideNode`), its
    /// eight children's boxes as structure of arrays: plane `p = 2·axis + side` (side 0 the
    /// minima, 1 the maxima) of children `4·h .. 4·h + 4` is `bounds[2·p + h]`. Empty slots
    /// hold the inverted box (+`f32::MAX`, −`f32::MAX`), which no ray enters. `children` is
    /// the CPU's `meta` (a word WGSL reserves): per child a node index, or `LEAF_BIT | (count −
    /// 1) << 29 | first`, both rebased into the shared buffers.
    pub struct WideNodeRecord(224) {
        /// Children's planes, four lanes to a vector.
        pub bounds: [[f32; 4]; 12],
        /// Children's node index or leaf range, four to a vector.
        pub children: [[u32; 4]; 2],
    }
}

gpu_struct! {
    /// Eight triangles of a mesh BVH's leaves as the CPU stores them
    /// (`crate::accel::bvh::TriBlock`): coordinate `axis` of vertex `k` of lanes `4·h .. 4·h +
    /// 4` is `v[2·(3·k + axis) + h]`; `slot` is `1 << child slot` of the lane's leaf (0 for an
    /// unused lane), `id` the triangle's index in its mesh.
    pub struct TriBlockRecord(352) {
        /// Vertex coordinates, four lanes to a vector.
        pub v: [[f32; 4]; 18],
        /// Each lane's leaf slot bit.
        pub slot: [[u32; 4]; 2],
        /// Each lane's triangle index.
        pub id: [[u32; 4]; 2],
    }
}

gpu_struct! {
    /// One mesh: its BLAS and where its vertex attributes start.
    pub struct MeshRecord(16) {
        /// Root node of the mesh's BVH, or [`NONE`] for a mesh with no valid triangle.
        pub root: u32,
        /// First vertex in the vertex buffer.
        pub vertex_start: u32,
        /// First triangle in the triangle-index buffer.
        pub triangle_start: u32,
        /// 1 when the mesh has texture coordinates.
        pub has_uvs: u32,
    }
}

gpu_struct! {
    /// A mesh vertex's shading attributes.
    pub struct VertexRecord(80) {
        /// Object-space position.
        pub position: [f32; 3],
        /// Texture coordinate u.
        pub u: f32,
        /// Object-space unit normal.
        pub normal: [f32; 3],
        /// Texture coordinate v.
        pub v: f32,
        /// Tangent and bitangent sign (`TriangleMesh::tangents`; (1, 0, 0, 1) without).
        pub tangent: [f32; 4],
        /// Vertex colour, linear RGBA (`TriangleMesh::colors`; white without).
        pub color: [f32; 4],
        /// Second texture coordinates (`TriangleMesh::uvs1`; zero without), then two zeros.
        pub uv1: [f32; 4],
    }
}

gpu_struct! {
    /// A triangle's vertex indices (relative to its mesh) and its file material.
    pub struct TriangleIndices(16) {
        /// First vertex.
        pub a: u32,
        /// Second vertex.
        pub b: u32,
        /// Third vertex.
        pub c: u32,
        /// Index into the file's materials.
        pub material: u32,
    }
}

gpu_struct! {
    /// A mesh instance: transforms and material mapping.
    pub struct InstanceRecord(112) {
        /// World → object, rows of a 3×4 matrix.
        pub world_to_object: [[f32; 4]; 3],
        /// Inverse transpose of the object → world linear part (maps normals), rows.
        pub normal_matrix: [[f32; 4]; 3],
        /// Index into the mesh records.
        pub mesh: u32,
        /// Scene material of the file's material 0.
        pub material_base: u32,
        /// Scene material replacing the file's, or [`NONE`].
        pub material_override: u32,
        /// 1 when hits need the alpha-mask test (`SceneMeshes::alpha_tested`), else 0.
        pub alpha_tested: u32,
    }
}

// The material records carry the tape's material lanes as vec4s.
const _: () = assert!(crate::sdf::tape::MATERIAL_FLOATS == 5 * 4);

gpu_struct! {
    /// A scene material: the lanes of `MaterialVec` and, for a mesh file's material, its
    /// textures (`MaterialTextures`) and alpha mode.
    pub struct MaterialRecord(304) {
        /// The lanes, four per vector.
        pub lanes: [[f32; 4]; 5],
        /// Per texture slot (base colour, metallic-roughness, normal, occlusion, emissive:
        /// `MaterialTextures::slots`), the `KHR_texture_transform` matrix as two vectors:
        /// (column 0, column 1) and (column 2, 0, 0) of `UvTransform::columns`.
        pub transforms: [[f32; 4]; 10],
        /// Per slot, the texture index with the texture coordinate set in bit 31, or
        /// [`NONE`]; entries 5–7 unused.
        pub slots: [[u32; 4]; 2],
        /// Alpha cutoff, base colour factor alpha, normal scale, occlusion strength.
        pub factors: [f32; 4],
        /// `ALPHA_*` of the alpha mode (`ALPHA_OPAQUE` for scene materials).
        pub alpha_mode: u32,
        /// Unused.
        pub pad0: u32,
        /// Unused.
        pub pad1: u32,
        /// Unused.
        pub pad2: u32,
    }
}

gpu_struct! {
    /// A texture in the shared texel buffer.
    pub struct TextureRecord(16) {
        /// First word of the texels in the texel buffer (row-major, row 0 at the top).
        pub texel_start: u32,
        /// Width in texels.
        pub width: u32,
        /// Height in texels.
        pub height: u32,
        /// Wrap modes: u in bits 0–3, v in bits 4–7 (`WRAP_*` constants); the texel format
        /// in bits 8 and 9 (`TEXELS_PACKED8`, `TEXELS_SRGB`).
        pub wrap: u32,
    }
}

gpu_struct! {
    /// Scene-wide values: the tracer settings and the roots of the BVHs.
    pub struct SceneGlobals(64) {
        /// ε at t = 0.
        pub epsilon: f32,
        /// Growth of ε per unit distance.
        pub epsilon_per_unit: f32,
        /// Maximum ray distance.
        pub max_distance: f32,
        /// Maximum sphere-tracing steps.
        pub max_steps: u32,
        /// Normal estimator (`NORMALS_*`).
        pub normals: u32,
        /// Number of SDF objects.
        pub object_count: u32,
        /// Root of the SDF objects' BVH, or [`NONE`].
        pub object_root: u32,
        /// First entry of the unbounded objects' list in the reference buffer.
        pub unbounded_start: u32,
        /// Number of unbounded objects.
        pub unbounded_count: u32,
        /// Number of mesh instances.
        pub instance_count: u32,
        /// Root of the instances' BVH, or [`NONE`].
        pub tlas_root: u32,
        /// Number of scene materials.
        pub material_count: u32,
        /// A ray's node-test margin in the instances' BVH is this times its origin's largest
        /// |component| (`InstanceBvh::origin_margin`).
        pub tlas_origin_margin: f32,
        /// Where the merged mesh's (instance, triangle) pairs start in the reference buffer
        /// (`InstanceBvh::merged`): a tree leaf naming instance `instance_count` is the merged
        /// mesh, and its triangle `k` stands for triangle `refs[start + 2k + 1]` of instance
        /// `refs[start + 2k]`.
        pub merged_origin_start: u32,
        /// Unused.
        pub pad2: u32,
        /// Unused.
        pub pad3: u32,
    }
}

gpu_struct! {
    /// One ray of a query batch.
    pub struct QueryRay(32) {
        /// Origin.
        pub origin: [f32; 3],
        /// Lower end of the interval.
        pub tmin: f32,
        /// Unit direction.
        pub direction: [f32; 3],
        /// Upper end of the interval.
        pub tmax: f32,
    }
}

gpu_struct! {
    /// The answer to one query ray.
    pub struct QueryResult(48) {
        /// Unit normal at the hit.
        pub normal: [f32; 3],
        /// Hit distance (meaningless on a miss).
        pub t: f32,
        /// `HIT_MISS`, `HIT_SDF` or `HIT_MESH`.
        pub kind: u32,
        /// SDF object or mesh instance.
        pub object: u32,
        /// 1 when the shadow query found the ray blocked.
        pub occluded: u32,
        /// Sphere-tracing steps.
        pub steps: u32,
        /// 1 when the driver cut the kernel invocation short (`loops_were_cut` in
        /// shaders/tape.wgsl): the answer is wrong.
        pub cut: u32,
        /// Unused.
        pub pad0: u32,
        /// Unused.
        pub pad1: u32,
        /// Unused.
        pub pad2: u32,
    }
}

/// Leaves of the walk one ray of the field probe kernel records in order (the rest are only
/// counted).
pub const FIELD_PROBE_LEAVES: u32 = 64;

gpu_struct! {
    /// The answer of the field probe kernel (`shaders/field_probe.wgsl`) for one ray of one
    /// object: point location and the field at the ray's origin, and the leaves the octree
    /// walk over the ray's interval meets, for checking both against the CPU.
    pub struct FieldProbeResult(288) {
        /// The field at the origin (`field_eval`).
        pub value: f32,
        /// The leaf holding the origin, or [`NONE`] outside the octree.
        pub leaf: u32,
        /// Leaves the walk met.
        pub count: u32,
        /// The first leaf met that is not proven empty (a surface or full leaf), or [`NONE`].
        pub first_surface: u32,
        /// Where the ray enters that leaf's box.
        pub first_enter: f32,
        /// Where it leaves it.
        pub first_exit: f32,
        /// Unused.
        pub pad0: u32,
        /// Unused.
        pub pad1: u32,
        /// The first [`FIELD_PROBE_LEAVES`] leaves met, in order.
        pub leaves: [[u32; 4]; FIELD_PROBE_LEAVES as usize / 4],
    }
}

gpu_struct! {
    /// Parameters of one chunk of a dispatch.
    pub struct ChunkParams(32) {
        /// First item of the chunk.
        pub first: u32,
        /// Items in the chunk.
        pub count: u32,
        /// Which pass of a multi-pass kernel runs (the probe kernel); 0 otherwise.
        pub part: u32,
        /// The query kernel: what to compute (`QUERY_*` bits).
        pub queries: u32,
        /// Tape evaluation and the field probe: the SDF object.
        pub object: u32,
        /// The probe kernel: the soft shadows' penumbra sharpness k.
        pub penumbra_k: f32,
        /// Padding to WGSL's 16-byte uniform alignment.
        pub pad0: u32,
        /// Padding.
        pub pad1: u32,
    }
}

gpu_struct! {
    /// The answers of the probe kernel (`shaders/probe.wgsl`) for one ray: the scene queries
    /// that shading uses, for checking them against the CPU.
    pub struct ProbeResult(128) {
        /// `scene_material` at the closest hit, as material lanes (zero on a miss).
        pub material: [[f32; 4]; 5],
        /// `scene_exit` from just inside the hit, along the ray: (t, normal), t < 0 for none.
        pub exit: [f32; 4],
        /// `scene_visibility` along the ray with `SHADOW_SOFT`.
        pub soft: f32,
        /// `scene_visibility` along the ray with `SHADOW_SOFT_IMPROVED`.
        pub soft_improved: f32,
        /// `scene_distance` at the ray's origin with reach 1.
        pub distance: f32,
        /// The closest hit's kind.
        pub kind: u32,
        /// 1 when the driver cut one of the ray's passes short (`loops_were_cut` in
        /// shaders/tape.wgsl): some answers are wrong.
        pub cut: u32,
        /// Unused.
        pub pad0: u32,
        /// Unused.
        pub pad1: u32,
        /// Unused.
        pub pad2: u32,
    }
}
