//! A scene in GPU buffers: every tape, the object bounds and their BVH, each object's field
//! octree of specialised tapes, meshes with their BVHs and the one over the instances,
//! materials and textures.
//!
//! [`SceneData`] is the host-side image of the buffers (plain vectors of the records in
//! [`crate::gpu::records`], built without a device, so its invariants are testable anywhere);
//! [`GpuScene`] uploads it and binds it as group 0 in the order of
//! [`crate::gpu::shaders::scene_bindings`].
//!
//! The BVHs are the CPU tracer's own ([`crate::accel::bvh`]: the SDF objects' `AabbBvh`, each
//! mesh's `MeshBvh` with its leaf triangles in blocks of eight, the instances' `InstanceBvh`),
//! taken from a [`SceneTracer`] node for node and rebased into shared buffers: inner children
//! offset by where the tree's nodes start, leaf ranges by where its blocks or references start.
//! Both backends thus walk one structure; a BVH change lands once. The WGSL node test is the
//! CPU's (entry and exit distances widened by `WIDEN`); as GPU arithmetic is less tightly
//! specified (a division may be off by 2.5 ulp, subnormals may flush), each child box is also
//! padded by a few ulps of its coordinates on upload, which can only add visits, never lose a
//! hit.
//!
//! The field octrees ([`crate::accel::field`]) are uploaded as the CPU holds them, rebased
//! into shared buffers: every object's nodes in one array (child and leaf indices offset by
//! where the object's nodes and leaves start), every leaf in another, every distinct leaf
//! tape as a [`TapeRef`] into the shared instruction buffer.

use super::GpuError;
use super::context::GpuContext;
use super::records::*;
use super::shaders::{
    BindingKind, bind_buffers, layout_entries, normals_code, scene_bindings, verdict_code,
    wrap_code,
};
use crate::accel::SdfAccel;
use crate::accel::bvh::{AabbBvh, FIRST_MASK, LEAF_BIT, MeshBvh, WideNode, leaf_first};
use crate::accel::field::{EMPTY_LEAF, FieldOctree, LEAF};
use crate::geom::Aabb;
use crate::scene::{Scene, TracerSettings};
use crate::sdf::tape::Tape;
use crate::trace::SceneTracer;
use glam::Vec3;

/// An instance's record: its world → object map and normal matrix as rows, its mesh record
/// and materials.
fn instance_record(
    world_to_object: &glam::Affine3A,
    normal_matrix: &glam::Mat3A,
    mesh: u32,
    material_base: u32,
    material_override: u32,
    alpha_tested: bool,
) -> InstanceRecord {
    let (x, y, z, t) = (
        world_to_object.matrix3.x_axis,
        world_to_object.matrix3.y_axis,
        world_to_object.matrix3.z_axis,
        world_to_object.translation,
    );
    let nm = normal_matrix;
    InstanceRecord {
        world_to_object: [
            [x.x, y.x, z.x, t.x],
            [x.y, y.y, z.y, t.y],
            [x.z, y.z, z.z, t.z],
        ],
        normal_matrix: [
            nm.x_axis.extend(0.0).to_array(),
            nm.y_axis.extend(0.0).to_array(),
            nm.z_axis.extend(0.0).to_array(),
        ],
        mesh,
        material_base,
        material_override,
        alpha_tested: alpha_tested as u32,
    }
}

/// The host-side contents of the scene buffers.
#[derive(Debug, Clone, Default)]
pub struct SceneData {
    /// Tracer settings and roots.
    pub globals: SceneGlobals,
    /// Instructions of every tape.
    pub instrs: Vec<InstrRecord>,
    /// SDF objects.
    pub objects: Vec<SdfObjectRecord>,
    /// Nodes of every object's field octree, rebased (see [`FieldLeafRecord`]).
    pub field_nodes: Vec<u32>,
    /// Leaves of every field octree.
    pub field_leaves: Vec<FieldLeafRecord>,
    /// The distinct distance and shading tapes of every field octree's leaves.
    pub field_tapes: Vec<TapeRef>,
    /// Nodes of every BVH (objects, instances, meshes).
    pub nodes: Vec<WideNodeRecord>,
    /// Object and instance indices referenced by leaves, then the unbounded objects.
    pub refs: Vec<u32>,
    /// The leaf triangles of every mesh, eight to a block.
    pub tri_blocks: Vec<TriBlockRecord>,
    /// Meshes.
    pub meshes: Vec<MeshRecord>,
    /// Vertex attributes of every mesh.
    pub vertices: Vec<VertexRecord>,
    /// Triangle vertex indices and materials of every mesh, in file order.
    pub triangle_indices: Vec<TriangleIndices>,
    /// Mesh instances, in scene order.
    pub instances: Vec<InstanceRecord>,
    /// Scene materials.
    pub materials: Vec<MaterialRecord>,
    /// Textures.
    pub textures: Vec<TextureRecord>,
    /// Texels of every texture.
    pub texels: Vec<u32>,
    /// Deepest BVH (levels), checked against [`STACK_SIZE`].
    pub max_depth: u32,
}

/// A child box padded by a few ulps of its largest coordinate (see the module documentation),
/// or `None` for an empty slot.
fn padded(lo: Vec3, hi: Vec3) -> Option<(Vec3, Vec3)> {
    if lo.cmpgt(hi).any() {
        return None;
    }
    let m = lo.abs().max(hi.abs()).max_element();
    let pad = Vec3::splat(64.0 * f32::EPSILON * m + f32::MIN_POSITIVE);
    Some((lo - pad, hi + pad))
}

/// Eight lanes as the two four-lane vectors of a GPU record.
fn halves<T: Copy + Default>(lanes: &[T; 8]) -> [[T; 4]; 2] {
    let mut out = [[T::default(); 4]; 2];
    for (i, &x) in lanes.iter().enumerate() {
        out[i / 4][i % 4] = x;
    }
    out
}

/// A gradient enclosure as the GPU records it: 1 and its ends when every end is finite, else
/// 0 and zeros (WGSL has no infinities to mark the whole line as the CPU does).
fn gradient_record(gradient: &[[f32; 3]; 2]) -> (u32, [[f32; 3]; 2]) {
    if gradient.iter().flatten().all(|g| g.is_finite()) {
        (1, *gradient)
    } else {
        (0, [[0.0; 3]; 2])
    }
}

/// Infinite coordinates as ±`f32::MAX` (GPU compilers need not preserve infinities).
fn finite_or_max(v: Vec3) -> [f32; 3] {
    v.to_array().map(|c| {
        if c.is_infinite() {
            f32::MAX.copysign(c)
        } else {
            c
        }
    })
}

fn tape_ref(tape: &Tape, instrs: &mut Vec<InstrRecord>) -> TapeRef {
    let r = TapeRef {
        start: instrs.len() as u32,
        len: tape.len() as u32,
        result: tape.result() as u32,
        material: tape.material_result().map_or(NONE, u32::from),
    };
    instrs.extend_from_slice(instr_records(tape.instrs()));
    r
}

impl SceneData {
    /// Builds the buffers of a scene, with the acceleration structures the CPU tracer builds
    /// ([`SceneTracer::new`]).
    pub fn from_scene(scene: &Scene) -> Result<Self, GpuError> {
        // refused before the structures are built for nothing
        supported(scene)?;
        Self::from_tracer(&SceneTracer::new(scene))
    }

    /// Builds the buffers of a scene from a CPU tracer's acceleration structures (its field
    /// octrees and BVHs), so that both backends walk the very same ones.
    pub fn from_tracer(tracer: &SceneTracer) -> Result<Self, GpuError> {
        let scene = tracer.scene();
        supported(scene)?;
        let fields = tracer.fields();
        let mut data = SceneData::default();
        data.set_tracer(&scene.tracer);

        // SDF objects: tapes, bounds and fields; the BVH over the finite boxes, the others
        // apart, as the CPU's `AabbBvh` holds them.
        for (object, field) in scene.objects.iter().zip(fields) {
            let distance = tape_ref(&field.whole, &mut data.instrs);
            let shading = tape_ref(&field.whole_shading, &mut data.instrs);
            let (field_root, field_box) = match &field.octree {
                Some(tree) => (data.add_field(tree)?, tree.bounds()),
                None => (NONE, Aabb::new(Vec3::ZERO, Vec3::ZERO)),
            };
            let marched_whole = field.octree.as_ref().is_some_and(|t| t.marched_whole());
            let b: Aabb = object.bounds();
            let nan = b.min.is_nan() || b.max.is_nan();
            let (outside_graded, [outside_lo, outside_hi]) = gradient_record(&field.outside);
            data.objects.push(SdfObjectRecord {
                lo: finite_or_max(b.min),
                nan_bounds: nan as u32,
                hi: finite_or_max(b.max),
                field_root,
                field_lo: field_box.min.to_array(),
                field_hi: field_box.max.to_array(),
                outside_graded,
                outside_lo,
                outside_hi,
                convex: field.convex.is_some() as u32,
                convex_relative: field.convex.map_or(0.0, |m| m.relative),
                convex_scale: field.convex.map_or(0.0, |m| m.scale),
                marched_whole: marched_whole as u32,
                reserved0: 0,
                reserved1: 0,
                reserved2: 0,
                distance,
                shading,
            });
        }
        // A tracer made with the linear scan (a check of the BVH) has no tree to share: the
        // GPU gets the one the BVH option would have built.
        let built;
        let objects = match tracer.sdf_accel() {
            SdfAccel::Bvh(b) => b,
            SdfAccel::Linear(bounds) => {
                built = AabbBvh::build(bounds);
                &built
            }
        };
        let refs_start = data.refs.len() as u32;
        data.refs.extend(objects.leaf_boxes());
        data.globals.object_root = data.add_tree(objects.wide_nodes(), refs_start)?;
        data.max_depth = data.max_depth.max(objects.stats().max_depth);
        data.globals.object_count = scene.objects.len() as u32;
        data.globals.unbounded_start = data.refs.len() as u32;
        data.globals.unbounded_count = objects.unbounded().len() as u32;
        data.refs.extend_from_slice(objects.unbounded());

        // Meshes: attributes in file order (the BVH keeps only the triangles that can be
        // hit), each mesh's tree with its leaf blocks.
        let sm = &scene.meshes;
        let accel = tracer.mesh_accel();
        for (mesh, bvh) in sm.meshes.iter().zip(&accel.blas) {
            let record_start = MeshRecord {
                root: NONE,
                vertex_start: data.vertices.len() as u32,
                triangle_start: data.triangle_indices.len() as u32,
                has_uvs: (!mesh.uvs.is_empty()) as u32,
            };
            for (k, (p, n)) in mesh.positions.iter().zip(&mesh.normals).enumerate() {
                let uv = mesh.uvs.get(k).copied().unwrap_or_default();
                data.vertices.push(VertexRecord {
                    position: p.to_array(),
                    u: uv.x,
                    normal: n.to_array(),
                    v: uv.y,
                    tangent: mesh
                        .tangents
                        .get(k)
                        .map_or([1.0, 0.0, 0.0, 1.0], |t| t.to_array()),
                    color: mesh.colors.get(k).map_or([1.0; 4], |c| c.to_array()),
                    uv1: mesh
                        .uvs1
                        .get(k)
                        .copied()
                        .unwrap_or_default()
                        .extend(0.0)
                        .extend(0.0)
                        .to_array(),
                });
            }
            for (t, idx) in mesh.triangles.iter().enumerate() {
                data.triangle_indices.push(TriangleIndices {
                    a: idx[0],
                    b: idx[1],
                    c: idx[2],
                    material: mesh.triangle_material.get(t).copied().unwrap_or(0),
                });
            }
            let root = data.add_mesh_tree(bvh)?;
            data.meshes.push(MeshRecord {
                root,
                ..record_start
            });
        }

        // The merged mesh of single-use instances (`accel::merge`): its tree and leaf blocks
        // only (a hit on it is looked up as the instance's own triangle, whose attributes are
        // above).
        let merged_mesh = data.meshes.len() as u32;
        if let Some(bvh) = accel.blas.get(sm.meshes.len()) {
            let root = data.add_mesh_tree(bvh)?;
            data.meshes.push(MeshRecord {
                root,
                vertex_start: 0,
                triangle_start: 0,
                has_uvs: 0,
            });
        }

        // Instances: all recorded (surfaces are looked up by scene index); the tree over the
        // valid ones is the CPU's, with its per-ray node margin.
        for (k, inst) in sm.instances.iter().enumerate() {
            data.instances.push(instance_record(
                &inst.transform.inverse(),
                &inst.normal_matrix,
                inst.mesh as u32,
                inst.material_base,
                inst.material_override.unwrap_or(NONE),
                accel.alpha_tested.get(k).copied().unwrap_or(false),
            ));
        }
        data.globals.instance_count = sm.instances.len() as u32;
        if let Some((index, origin)) = accel.tlas.merged() {
            debug_assert_eq!(index, data.globals.instance_count);
            // Untransformed, and never alpha-tested (no merged instance has a mask).
            data.instances.push(instance_record(
                &glam::Affine3A::IDENTITY,
                &glam::Mat3A::IDENTITY,
                merged_mesh,
                0,
                NONE,
                false,
            ));
            data.globals.merged_origin_start = data.refs.len() as u32;
            data.refs.extend(
                origin
                    .iter()
                    .flat_map(|&(instance, triangle)| [instance, triangle]),
            );
        }
        let refs_start = data.refs.len() as u32;
        data.refs.extend(accel.tlas.leaf_instances());
        data.globals.tlas_root = data.add_tree(accel.tlas.wide_nodes(), refs_start)?;
        data.globals.tlas_origin_margin = accel.tlas.origin_margin();
        data.max_depth = data.max_depth.max(accel.tlas.stats().max_depth);

        // Materials: the scene's table (mesh files' materials included) and their textures.
        for (i, m) in scene.materials.iter().enumerate() {
            let v = m.to_vec();
            let file = (i as u32)
                .checked_sub(sm.material_offset)
                .and_then(|k| sm.materials.get(k as usize));
            data.materials.push(material_record(&v, file));
        }
        data.globals.material_count = data.materials.len() as u32;
        for t in &sm.textures {
            // a texture with missing texels samples as white, as Texture::sample does
            let complete = (t.texels.len() as u64) >= u64::from(t.width) * u64::from(t.height);
            let (width, height) = if complete {
                (t.width, t.height)
            } else {
                (0, 0)
            };
            let packed = if complete { t.packed8() } else { None };
            let mut format = 0;
            if packed.is_some() {
                format |= TEXELS_PACKED8;
                if t.srgb {
                    format |= TEXELS_SRGB;
                }
            }
            data.textures.push(TextureRecord {
                texel_start: data.texels.len() as u32,
                width,
                height,
                wrap: wrap_code(t.wrap_u) | (wrap_code(t.wrap_v) << 4) | format,
            });
            match packed {
                Some(p) => data.texels.extend(p),
                None if complete => data.texels.extend(
                    t.texels[..(t.width as usize * t.height as usize)]
                        .iter()
                        .flat_map(|c| c.to_array().map(f32::to_bits)),
                ),
                None => {}
            }
        }
        data.check_depth()?;
        Ok(data)
    }

    /// Buffers holding only `tapes`, as SDF objects with unknown bounds and no tracer
    /// settings (the tape evaluation kernel reads object i's distance tape).
    pub fn from_tapes(tapes: &[&Tape]) -> Self {
        let mut data = SceneData::default();
        data.globals.object_root = NONE;
        data.globals.tlas_root = NONE;
        for tape in tapes {
            let distance = tape_ref(tape, &mut data.instrs);
            data.objects.push(SdfObjectRecord {
                nan_bounds: 1,
                field_root: NONE,
                distance,
                shading: distance,
                ..Default::default()
            });
        }
        data.globals.object_count = tapes.len() as u32;
        data
    }

    /// Appends an object's octree (its nodes rebased to the shared buffers, its leaves and
    /// their tapes) and returns the index of its root node.
    fn add_field(&mut self, tree: &FieldOctree) -> Result<u32, GpuError> {
        let raw = tree.raw_nodes();
        let (node_base, leaf_base) = (self.field_nodes.len(), self.field_leaves.len());
        // indices share a word with the leaf bit
        if node_base + raw.len() >= LEAF as usize
            || leaf_base + tree.leaves().len() >= LEAF as usize
        {
            return Err(GpuError::Unsupported(format!(
                "the scene's field octrees have more than {LEAF} nodes"
            )));
        }
        let tape_base = self.field_tapes.len() as u32;
        let shading_base = tape_base + tree.tapes.len() as u32;
        for tape in tree.tapes.iter().chain(&tree.shading) {
            let r = tape_ref(tape, &mut self.instrs);
            self.field_tapes.push(r);
        }
        self.field_leaves.extend(tree.leaves().iter().map(|l| {
            let (graded, [lo, hi]) = gradient_record(&l.gradient);
            FieldLeafRecord {
                gradient_lo: lo,
                tape: tape_base + l.tape,
                gradient_hi: hi,
                shading: shading_base + l.shading,
                verdict: verdict_code(l.verdict),
                min_value: l.min_value,
                graded,
                pad: 0,
            }
        }));
        let (node_base, leaf_base) = (node_base as u32, leaf_base as u32);
        self.field_nodes.extend(raw.iter().map(|&n| {
            // the walk here reads each leaf's verdict from its record
            if n & LEAF != 0 {
                LEAF | ((n & !(LEAF | EMPTY_LEAF)) + leaf_base)
            } else {
                n + node_base
            }
        }));
        Ok(node_base)
    }

    fn set_tracer(&mut self, s: &TracerSettings) {
        self.globals.epsilon = s.epsilon;
        self.globals.epsilon_per_unit = s.epsilon_per_unit;
        self.globals.max_distance = s.max_distance;
        self.globals.max_steps = s.max_steps;
        self.globals.normals = normals_code(s.normals);
        self.globals.object_root = NONE;
        self.globals.tlas_root = NONE;
    }

    /// Appends a mesh's tree and its leaf blocks; returns its root ([`NONE`] when empty).
    fn add_mesh_tree(&mut self, bvh: &MeshBvh) -> Result<u32, GpuError> {
        let leaves = bvh.leaf_blocks();
        let blocks_start = self.tri_blocks.len() as u32;
        for (block, ids) in leaves.blocks.iter().zip(leaves.ids.iter()) {
            let mut r = TriBlockRecord::default();
            for (row, lanes) in block.v.iter().enumerate() {
                [r.v[2 * row], r.v[2 * row + 1]] = halves(lanes);
            }
            r.slot = halves(&block.slot);
            r.id = halves(ids);
            self.tri_blocks.push(r);
        }
        let root = self.add_tree(bvh.wide_nodes(), blocks_start)?;
        self.max_depth = self.max_depth.max(bvh.stats().max_depth);
        Ok(root)
    }

    /// Appends a wide tree's nodes, rebased: inner children by where its nodes start, leaf
    /// ranges by `leaf_base` (where its primitives or blocks start in their buffer). Returns
    /// the root's index ([`NONE`] for an empty tree).
    fn add_tree(&mut self, nodes: &[WideNode], leaf_base: u32) -> Result<u32, GpuError> {
        if nodes.is_empty() {
            return Ok(NONE);
        }
        let base = self.nodes.len() as u32;
        let too_many = || {
            GpuError::Unsupported(format!(
                "the scene's BVHs have more than {FIRST_MASK} nodes or leaf entries"
            ))
        };
        if (base as usize + nodes.len()) as u64 > u64::from(FIRST_MASK) {
            return Err(too_many());
        }
        for n in nodes {
            let mut r = WideNodeRecord::default();
            for slot in 0..8 {
                let lo = Vec3::new(n.bounds[0][slot], n.bounds[2][slot], n.bounds[4][slot]);
                let hi = Vec3::new(n.bounds[1][slot], n.bounds[3][slot], n.bounds[5][slot]);
                // Infinities as ±f32::MAX (GPU compilers need not preserve them): an empty
                // slot stays inverted.
                let (lo, hi) = padded(lo, hi).unwrap_or((Vec3::MAX, Vec3::MIN));
                for axis in 0..3 {
                    let (p_lo, p_hi) = (2 * axis, 2 * axis + 1);
                    r.bounds[2 * p_lo + slot / 4][slot % 4] = lo[axis];
                    r.bounds[2 * p_hi + slot / 4][slot % 4] = hi[axis];
                }
                let m = n.meta[slot];
                r.children[slot / 4][slot % 4] = if lo.cmpgt(hi).any() {
                    0
                } else if m & LEAF_BIT != 0 {
                    let first = leaf_first(m) + leaf_base;
                    if first > FIRST_MASK {
                        return Err(too_many());
                    }
                    (m & !FIRST_MASK) | first
                } else {
                    m + base
                };
            }
            self.nodes.push(r);
        }
        Ok(base)
    }

    fn check_depth(&self) -> Result<(), GpuError> {
        // a visited node replaces its entry by up to eight children: 7·depth + 1 entries
        if 7 * self.max_depth + 1 > STACK_SIZE {
            return Err(GpuError::Unsupported(format!(
                "a BVH is {} levels deep, the GPU traversal stacks hold {} levels",
                self.max_depth,
                (STACK_SIZE - 1) / 7
            )));
        }
        Ok(())
    }

    /// The bytes of each buffer, in binding order.
    pub fn buffers(&self) -> Vec<(&'static str, &[u8])> {
        let bytes: Vec<&[u8]> = vec![
            bytemuck::bytes_of(&self.globals),
            bytemuck::cast_slice(&self.instrs),
            bytemuck::cast_slice(&self.objects),
            bytemuck::cast_slice(&self.field_nodes),
            bytemuck::cast_slice(&self.field_leaves),
            bytemuck::cast_slice(&self.field_tapes),
            bytemuck::cast_slice(&self.nodes),
            bytemuck::cast_slice(&self.refs),
            bytemuck::cast_slice(&self.tri_blocks),
            bytemuck::cast_slice(&self.meshes),
            bytemuck::cast_slice(&self.vertices),
            bytemuck::cast_slice(&self.triangle_indices),
            bytemuck::cast_slice(&self.instances),
            bytemuck::cast_slice(&self.materials),
            bytemuck::cast_slice(&self.textures),
            bytemuck::cast_slice(&self.texels),
        ];
        let names = scene_bindings();
        assert_eq!(names.len(), bytes.len(), "one buffer per scene binding");
        names.iter().map(|n| n.0).zip(bytes).collect()
    }
}

/// Whether the GPU tracer handles the scene's settings: it implements Hart's stepper only; the
/// over-relaxed ones and segment tracing (which needs the interval evaluator of
/// `sdf::interval`) are CPU steppers measured by `hytrace bench`.
pub(crate) fn supported(scene: &Scene) -> Result<(), GpuError> {
    if scene.tracer.stepper != crate::scene::Stepper::Hart {
        return Err(GpuError::Unsupported(format!(
            "tracer.stepper {:?}: the GPU traces with Hart's stepper only (use --backend cpu)",
            scene.tracer.stepper
        )));
    }
    Ok(())
}

/// The bind group layout of the scene buffers (group 0), the same for every scene.
pub fn scene_layout(ctx: &GpuContext) -> wgpu::BindGroupLayout {
    ctx.device
        .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("hytrace scene"),
            entries: &layout_entries(&scene_bindings()),
        })
}

/// A scene uploaded to the device, bound as group 0.
pub struct GpuScene {
    /// The bind group of the scene buffers.
    pub bind_group: wgpu::BindGroup,
    /// Its layout (the same for every scene, see [`scene_layout`]).
    pub layout: wgpu::BindGroupLayout,
    /// Bytes uploaded.
    pub bytes: u64,
    buffers: Vec<wgpu::Buffer>,
}

impl GpuScene {
    /// Uploads a scene's buffers; fails when one exceeds the device's binding size limit.
    pub fn new(ctx: &GpuContext, data: &SceneData) -> Result<Self, GpuError> {
        let layout = scene_layout(ctx);
        let limit = ctx.limits().max_storage_buffer_binding_size;
        let mut buffers = Vec::new();
        let mut total = 0;
        for ((name, bytes), (_, kind, _)) in data.buffers().into_iter().zip(scene_bindings()) {
            if bytes.len() as u64 > limit {
                return Err(GpuError::Unsupported(format!(
                    "the scene's `{name}` buffer takes {} bytes, the device binds at most {limit}",
                    bytes.len()
                )));
            }
            total += bytes.len() as u64;
            buffers.push(match kind {
                BindingKind::Uniform => ctx.uniform_buffer(name, bytes),
                BindingKind::Storage => ctx.storage_buffer(name, bytes, false),
                BindingKind::StorageReadWrite => ctx.storage_buffer(name, bytes, true),
            });
        }
        let refs: Vec<&wgpu::Buffer> = buffers.iter().collect();
        let bind_group = bind_buffers(&ctx.device, "hytrace scene", &layout, &refs);
        Ok(GpuScene {
            bind_group,
            layout,
            bytes: total,
            buffers,
        })
    }

    /// The uploaded buffers, in binding order.
    pub fn buffers(&self) -> &[wgpu::Buffer] {
        &self.buffers
    }
}

/// The record of a scene material whose lanes are `lanes`; `file` is the mesh file's
/// material it comes from, if any (its textures and alpha mode).
fn material_record(
    lanes: &crate::sdf::tape::MaterialVec,
    file: Option<&crate::scene::mesh::MeshMaterial>,
) -> MaterialRecord {
    use crate::scene::mesh::AlphaMode;
    let mut r = MaterialRecord {
        lanes: std::array::from_fn(|i| std::array::from_fn(|j| lanes[4 * i + j])),
        slots: [[NONE; 4]; 2],
        factors: [0.5, 1.0, 1.0, 1.0],
        alpha_mode: ALPHA_OPAQUE,
        ..Default::default()
    };
    let Some(m) = file else {
        return r;
    };
    for (k, slot) in m.textures.slots().into_iter().enumerate() {
        let Some(t) = slot else { continue };
        r.slots[k / 4][k % 4] = (t.texture as u32 & 0x7fff_ffff) | (t.tex_coord.min(1) << 31);
        let [c0, c1, c2] = t.transform.columns();
        r.transforms[2 * k] = [c0[0], c0[1], c1[0], c1[1]];
        r.transforms[2 * k + 1] = [c2[0], c2[1], 0.0, 0.0];
    }
    let (cutoff, mode) = match m.alpha_mode {
        AlphaMode::Opaque => (0.5, ALPHA_OPAQUE),
        AlphaMode::Mask { cutoff } => (cutoff, ALPHA_MASK),
        AlphaMode::Blend => (0.5, ALPHA_BLEND),
    };
    r.alpha_mode = mode;
    r.factors = [
        cutoff,
        m.base_alpha,
        m.textures.normal.map_or(1.0, |n| n.1),
        m.textures.occlusion.map_or(1.0, |o| o.1),
    ];
    r
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use std::path::Path;

    /// A twisted, bent composite (a tape whose leaves save most of it, so a deep octree pays)
    /// beside a plain sphere (whose tape is too short to split: an octree of one leaf).
    fn scene() -> Scene {
        let src = "Scene(
            camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
            objects: [
                (shape: Sphere(radius: 0.5), translate: (3, 0, 0)),
                (shape: Bend(rate: 0.5, shape: Twist(rate: 2.5, shape: Union([
                    Subtraction(base: RoundBox(half_extents: (0.28, 0.75, 0.28), radius: 0.04),
                        cut: Cylinder(half_height: 0.9, radius: 0.14)),
                    Transform(translate: (0, 0.4, 0), shape: Torus(major: 0.36, minor: 0.05)),
                    Transform(translate: (0, -0.4, 0), shape: Torus(major: 0.36, minor: 0.05))])))),
            ],
        )";
        Scene::from_source(src, Path::new("gpu-fields.ron")).unwrap_or_else(|e| panic!("{e}"))
    }

    /// The rebased buffers describe the CPU's octree: a host-side descent through
    /// `field_nodes` from the object's root reaches the record of the leaf
    /// `FieldOctree::locate` finds, whose tape references hold that leaf's instructions.
    #[test]
    fn uploaded_octrees_are_the_cpu_octrees_rebased() {
        let scene = scene();
        let tracer = SceneTracer::new(&scene);
        let fields = tracer.fields();
        let small = fields[0]
            .octree
            .as_ref()
            .expect("every object has an octree");
        assert_eq!(small.leaves().len(), 1);
        assert!(fields[1].octree.as_ref().unwrap().leaves().len() > 1);
        let data = SceneData::from_tracer(&tracer).unwrap();
        assert_ne!(data.objects[0].field_root, NONE);
        let obj = data.objects[1];
        let tree = fields[1].octree.as_ref().unwrap();
        assert_eq!(Vec3::from(obj.field_lo), tree.bounds().min);
        assert_eq!(Vec3::from(obj.field_hi), tree.bounds().max);
        let instrs = |r: &TapeRef| &data.instrs[r.start as usize..(r.start + r.len) as usize];
        let mut rng = Rng::new(3);
        for _ in 0..2000 {
            let p = rng.in_box(tree.bounds().min, tree.bounds().max);
            let cell = tree.locate(p).expect("inside");
            let (mut lo, mut hi) = (Vec3::from(obj.field_lo), Vec3::from(obj.field_hi));
            let mut node = data.field_nodes[obj.field_root as usize];
            while node & LEAF == 0 {
                let mid = 0.5 * (lo + hi);
                let up = p.cmpge(mid);
                node = data.field_nodes[(node + up.bitmask()) as usize];
                lo = Vec3::select(up, mid, lo);
                hi = Vec3::select(up, hi, mid);
            }
            assert_eq!((lo, hi), (cell.lo, cell.hi));
            let leaf = data.field_leaves[(node & !LEAF) as usize];
            assert_eq!(leaf.verdict, verdict_code(cell.leaf.verdict));
            assert_eq!(leaf.graded == 1, cell.leaf.gradient[0][0].is_finite());
            assert_eq!(leaf.min_value, cell.leaf.min_value);
            let tape = data.field_tapes[leaf.tape as usize];
            assert_eq!(instrs(&tape), instr_records(cell.tape.instrs()));
            assert_eq!(tape.result, u32::from(cell.tape.result()));
            let shading = data.field_tapes[leaf.shading as usize];
            assert_eq!(instrs(&shading), instr_records(cell.shading.instrs()));
            assert_eq!(
                shading.material,
                cell.shading.material_result().map_or(NONE, u32::from)
            );
        }
    }

    /// The uploaded BVHs are the CPU tracer's trees rebased: every used child's box contains
    /// the CPU's (padded, never shrunk), empty slots stay empty, and inner children and leaf
    /// ranges point where the CPU's do, offset by where the tree starts.
    #[test]
    fn uploaded_bvhs_are_the_cpu_trees_rebased() {
        let mut src = String::from(
            "Scene(camera: Perspective(position: (0, 0, 30), look_at: (0, 0, 0), fov: 40), objects: [",
        );
        for i in 0..300 {
            let (x, y, z) = ((i % 10) as f32, ((i / 10) % 10) as f32, (i / 100) as f32);
            src += &format!("(shape: Sphere(radius: 0.3), translate: ({x}, {y}, {z})),");
        }
        src += "(shape: Plane(normal: (0, 1, 0), offset: 1))])";
        let scene = Scene::from_source(&src, Path::new("gpu-bvh.ron")).unwrap();
        let tracer = SceneTracer::new(&scene);
        let data = SceneData::from_tracer(&tracer).unwrap();
        let SdfAccel::Bvh(cpu) = tracer.sdf_accel() else {
            panic!("the tracer's BVH")
        };
        let cpu_nodes = cpu.wide_nodes();
        assert!(cpu_nodes.len() > 10);
        let base = data.globals.object_root as usize;
        assert_eq!(data.nodes.len(), base + cpu_nodes.len());
        let leaf_refs: Vec<u32> = cpu.leaf_boxes().collect();
        for (k, (gpu, cpu)) in data.nodes[base..].iter().zip(cpu_nodes).enumerate() {
            for slot in 0..8 {
                let plane = |p: usize| gpu.bounds[2 * p + slot / 4][slot % 4];
                let meta = gpu.children[slot / 4][slot % 4];
                let empty = cpu.bounds[0][slot] > cpu.bounds[1][slot];
                for p in 0..6 {
                    let (g, c) = (plane(p), cpu.bounds[p][slot]);
                    if empty {
                        assert!(
                            plane(0) > plane(1),
                            "node {k} slot {slot}: empty slot entered"
                        );
                    } else if p % 2 == 0 {
                        assert!(g <= c, "node {k} slot {slot} plane {p}: {g} > {c}");
                    } else {
                        assert!(g >= c, "node {k} slot {slot} plane {p}: {g} < {c}");
                    }
                }
                if empty {
                    continue;
                }
                let m = cpu.meta[slot];
                if m & LEAF_BIT == 0 {
                    assert_eq!(meta, m + base as u32);
                } else {
                    let (first, count) = (leaf_first(m), ((m >> 29) & 3) + 1);
                    assert_eq!(meta & !FIRST_MASK, m & !FIRST_MASK, "leaf tag and count");
                    let at = leaf_first(meta) as usize;
                    assert_eq!(
                        &data.refs[at..at + count as usize],
                        &leaf_refs[first as usize..(first + count) as usize]
                    );
                }
            }
        }
        // the plane is the one unbounded object
        let unbounded = data.globals.unbounded_start as usize;
        assert_eq!(data.globals.unbounded_count, 1);
        assert_eq!(data.refs[unbounded], 300);
    }
}
