//! A scene in GPU buffers: every tape, the object bounds and their BVH, each object's field
//! octree of specialised tapes, meshes with a BVH2 per mesh and one over the instances,
//! materials and textures.
//!
//! [`SceneData`] is the host-side image of the buffers (plain vectors of the records in
//! [`crate::gpu::records`], built without a device, so its invariants are testable anywhere);
//! [`GpuScene`] uploads it and binds it as group 0 in the order of
//! [`crate::gpu::shaders::scene_bindings`].
//!
//! The BVHs are BVH2s built by obvhs (PLOC, Meister & Bittner 2018, with reinsertion) and
//! flattened here: inner nodes have their two children side by side, leaves point into the
//! triangle records (stored in leaf order) or the reference list (object and instance
//! indices). Node boxes are padded by a few ulps of their coordinates so that the slab test's
//! rounding never culls a triangle the watertight test would hit.
//!
//! The field octrees ([`crate::accel::field`]) are uploaded as the CPU holds them, rebased
//! into shared buffers: every object's nodes in one array (child and leaf indices offset by
//! where the object's nodes and leaves start), every leaf in another, every distinct leaf
//! tape as a [`TapeRef`] into the shared instruction buffer.

use super::GpuError;
use super::context::GpuContext;
use super::records::*;
use super::shaders::{BindingKind, normals_code, scene_bindings, verdict_code, wrap_code};
use crate::accel::field::{FieldOctree, LEAF, ObjectField};
use crate::accel::triangle;
use crate::geom::Aabb;
use crate::scene::{Scene, TracerSettings};
use crate::sdf::tape::Tape;
use glam::{Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb as OAabb;

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
    pub nodes: Vec<BvhNode>,
    /// Object and instance indices referenced by leaves, then the unbounded objects.
    pub refs: Vec<u32>,
    /// Triangles of every mesh in leaf order.
    pub triangles: Vec<TriangleRecord>,
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
    pub texels: Vec<[f32; 4]>,
    /// Deepest BVH (levels), checked against [`STACK_SIZE`].
    pub max_depth: u32,
}

fn oaabb(lo: Vec3, hi: Vec3) -> OAabb {
    OAabb::new(Vec3A::from(lo), Vec3A::from(hi))
}

/// A few ulps of the box's largest coordinate: the slab test's rounding stays inside.
fn padded(lo: Vec3, hi: Vec3) -> (Vec3, Vec3) {
    let m = lo.abs().max(hi.abs()).max_element();
    let pad = Vec3::splat(64.0 * f32::EPSILON * m + f32::MIN_POSITIVE);
    (lo - pad, hi + pad)
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
    /// Builds the buffers of a scene, with the fields the CPU tracer would build
    /// ([`crate::trace::build_fields`]).
    pub fn from_scene(scene: &Scene) -> Result<Self, GpuError> {
        // refused before the octrees are built for nothing
        supported(scene)?;
        Self::from_fields(scene, &crate::trace::build_fields(scene, true))
    }

    /// Builds the buffers of a scene whose objects' fields are built already (one per object,
    /// in scene order: `SceneTracer::fields`), so that both backends walk the same octrees.
    pub fn from_fields(scene: &Scene, fields: &[ObjectField]) -> Result<Self, GpuError> {
        if fields.len() != scene.objects.len() {
            return Err(GpuError::Unsupported(format!(
                "{} fields for {} SDF objects",
                fields.len(),
                scene.objects.len()
            )));
        }
        supported(scene)?;
        let mut data = SceneData::default();
        data.set_tracer(&scene.tracer);
        let quality = scene.tracer.bvh.params();

        // SDF objects: tapes, bounds, a BVH over the finite boxes, the others apart.
        let mut boxes = Vec::new();
        let mut boxed = Vec::new();
        let mut unbounded = Vec::new();
        for (i, (object, field)) in scene.objects.iter().zip(fields).enumerate() {
            let distance = tape_ref(&field.whole, &mut data.instrs);
            let shading = tape_ref(&field.whole_shading, &mut data.instrs);
            let (field_root, field_box) = match &field.octree {
                Some(tree) => (data.add_field(tree)?, tree.bounds()),
                None => (NONE, Aabb::new(Vec3::ZERO, Vec3::ZERO)),
            };
            let b: Aabb = object.bounds();
            let nan = b.min.is_nan() || b.max.is_nan();
            data.objects.push(SdfObjectRecord {
                lo: finite_or_max(b.min),
                nan_bounds: nan as u32,
                hi: finite_or_max(b.max),
                field_root,
                field_lo: field_box.min.to_array(),
                field_hi: field_box.max.to_array(),
                distance,
                shading,
                ..Default::default()
            });
            // as AabbBvh::build: empty boxes are never visited, infinite or NaN ones always
            if b.min.cmpgt(b.max).any() {
                continue;
            } else if !b.is_finite() {
                unbounded.push(i as u32);
            } else {
                boxes.push(oaabb(b.min, b.max));
                boxed.push(i as u32);
            }
        }
        let mut object_params = quality;
        object_params.max_prims_per_leaf = 2;
        data.globals.object_root = data.add_bvh(&boxes, object_params, |data, order| {
            let first = data.refs.len() as u32;
            data.refs.extend(order.iter().map(|&k| boxed[k as usize]));
            first
        });
        data.globals.object_count = scene.objects.len() as u32;
        data.globals.unbounded_start = data.refs.len() as u32;
        data.globals.unbounded_count = unbounded.len() as u32;
        data.refs.extend_from_slice(&unbounded);

        // Meshes: attributes in file order, a BVH over the valid triangles (as MeshBvh::build:
        // out-of-range, non-finite and zero-area triangles cannot be hit and are left out).
        let sm = &scene.meshes;
        let mut mesh_boxes = Vec::with_capacity(sm.meshes.len());
        for mesh in &sm.meshes {
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
                });
            }
            let mut kept = Vec::new();
            let mut tri_boxes = Vec::new();
            for (t, idx) in mesh.triangles.iter().enumerate() {
                data.triangle_indices.push(TriangleIndices {
                    a: idx[0],
                    b: idx[1],
                    c: idx[2],
                    material: mesh.triangle_material.get(t).copied().unwrap_or(0),
                });
                let v = idx.map(|k| mesh.positions.get(k as usize).copied());
                let [Some(a), Some(b), Some(c)] = v else {
                    continue;
                };
                if !triangle::is_finite(a, b, c) || triangle::is_degenerate(a, b, c) {
                    continue;
                }
                kept.push((t as u32, [a, b, c]));
                tri_boxes.push(oaabb(a.min(b).min(c), a.max(b).max(c)));
            }
            let root = data.add_bvh(&tri_boxes, quality, |data, order| {
                let first = data.triangles.len() as u32;
                data.triangles.extend(order.iter().map(|&k| {
                    let (id, [a, b, c]) = kept[k as usize];
                    TriangleRecord {
                        a: a.to_array(),
                        id,
                        b: b.to_array(),
                        pad0: 0,
                        c: c.to_array(),
                        pad1: 0,
                    }
                }));
                first
            });
            mesh_boxes.push((root != NONE).then(|| {
                let n = data.nodes[root as usize];
                (Vec3::from(n.lo), Vec3::from(n.hi))
            }));
            data.meshes.push(MeshRecord {
                root,
                ..record_start
            });
        }

        // Instances: all recorded (surfaces are looked up by scene index), the valid ones in
        // the TLAS (as InstanceBvh::build: a known, non-empty mesh and an invertible, finite
        // transform).
        let mut inst_boxes = Vec::new();
        let mut placed = Vec::new();
        for (i, inst) in sm.instances.iter().enumerate() {
            let m = inst.transform;
            let inv = m.inverse();
            let rows = |a: &glam::Affine3A| -> [[f32; 4]; 3] {
                let (x, y, z, t) = (
                    a.matrix3.x_axis,
                    a.matrix3.y_axis,
                    a.matrix3.z_axis,
                    a.translation,
                );
                [
                    [x.x, y.x, z.x, t.x],
                    [x.y, y.y, z.y, t.y],
                    [x.z, y.z, z.z, t.z],
                ]
            };
            let nm = inst.normal_matrix;
            data.instances.push(InstanceRecord {
                world_to_object: rows(&inv),
                normal_matrix: [
                    nm.x_axis.extend(0.0).to_array(),
                    nm.y_axis.extend(0.0).to_array(),
                    nm.z_axis.extend(0.0).to_array(),
                ],
                mesh: inst.mesh as u32,
                material_base: inst.material_base,
                material_override: inst.material_override.unwrap_or(NONE),
                pad: 0,
            });
            let Some(Some((lo, hi))) = mesh_boxes.get(inst.mesh) else {
                continue;
            };
            let finite = |a: &glam::Affine3A| {
                a.matrix3.x_axis.is_finite()
                    && a.matrix3.y_axis.is_finite()
                    && a.matrix3.z_axis.is_finite()
                    && a.translation.is_finite()
            };
            if !(m.matrix3.determinant() != 0.0 && finite(&m) && finite(&inv)) {
                continue;
            }
            let world = Aabb::new(*lo, *hi).transformed(&m);
            // The object-space ray is the world ray's exact preimage only up to rounding
            // amplified by the transform's condition number (see InstanceBvh::build): pad by
            // that, generously, relative to the box and the scene's scale.
            let frob = |a: &glam::Affine3A| {
                (a.matrix3.x_axis.length_squared()
                    + a.matrix3.y_axis.length_squared()
                    + a.matrix3.z_axis.length_squared())
                .sqrt()
            };
            let cond = frob(&m) * frob(&inv);
            let scale = world.min.abs().max(world.max.abs()).max_element();
            let pad = Vec3::splat(1024.0 * f32::EPSILON * cond * scale);
            inst_boxes.push(oaabb(world.min - pad, world.max + pad));
            placed.push(i as u32);
        }
        data.globals.instance_count = sm.instances.len() as u32;
        data.globals.tlas_root = data.add_bvh(&inst_boxes, quality, |data, order| {
            let first = data.refs.len() as u32;
            data.refs.extend(order.iter().map(|&k| placed[k as usize]));
            first
        });

        // Materials: the scene's table (mesh files' materials included) and their textures.
        for (i, m) in scene.materials.iter().enumerate() {
            let v = m.to_vec();
            let texture = (i as u32)
                .checked_sub(sm.material_offset)
                .and_then(|k| sm.materials.get(k as usize))
                .and_then(|mm| mm.base_color_texture)
                .map_or(NONE, |t| t as u32);
            data.materials.push(MaterialRecord {
                lanes: [
                    [v[0], v[1], v[2], v[3]],
                    [v[4], v[5], v[6], v[7]],
                    [v[8], v[9], v[10], v[11]],
                ],
                texture,
                ..Default::default()
            });
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
            data.textures.push(TextureRecord {
                texel_start: data.texels.len() as u32,
                width,
                height,
                wrap: wrap_code(t.wrap_u) | (wrap_code(t.wrap_v) << 4),
            });
            if complete {
                data.texels.extend(
                    t.texels[..(t.width as usize * t.height as usize)]
                        .iter()
                        .map(|c| c.to_array()),
                );
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
            let graded = l.gradient.iter().flatten().all(|g| g.is_finite());
            let [lo, hi] = if graded { l.gradient } else { [[0.0; 3]; 2] };
            FieldLeafRecord {
                gradient_lo: lo,
                tape: tape_base + l.tape,
                gradient_hi: hi,
                shading: shading_base + l.shading,
                verdict: verdict_code(l.verdict),
                min_value: l.min_value,
                graded: graded as u32,
                pad: 0,
            }
        }));
        let (node_base, leaf_base) = (node_base as u32, leaf_base as u32);
        self.field_nodes.extend(raw.iter().map(|&n| {
            if n & LEAF != 0 {
                LEAF | ((n & !LEAF) + leaf_base)
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

    /// Builds a BVH2 over `boxes`, appends its nodes and returns the root ([`NONE`] for no
    /// boxes). `place(data, order)` stores the primitives in leaf order (`order[k]` is the
    /// index into `boxes` of the k-th primitive) and returns where the first one went.
    fn add_bvh(
        &mut self,
        boxes: &[OAabb],
        params: BvhBuildParams,
        place: impl FnOnce(&mut SceneData, &[u32]) -> u32,
    ) -> u32 {
        if boxes.is_empty() {
            return NONE;
        }
        let mut build_time = std::time::Duration::ZERO;
        let bvh = obvhs::bvh2::builder::build_bvh2(boxes, params, &mut build_time);
        let first_prim = place(self, &bvh.primitive_indices);
        let base = self.nodes.len() as u32;
        for n in &bvh.nodes {
            let (lo, hi) = padded(Vec3::from(n.aabb.min), Vec3::from(n.aabb.max));
            let leaf = n.prim_count > 0;
            self.nodes.push(BvhNode {
                lo: lo.to_array(),
                first: if leaf {
                    first_prim + n.first_index
                } else {
                    base + n.first_index
                },
                hi: hi.to_array(),
                count: n.prim_count,
            });
        }
        let depth = depth_of(&self.nodes, base);
        self.max_depth = self.max_depth.max(depth);
        base
    }

    fn check_depth(&self) -> Result<(), GpuError> {
        // the walks push two children per inner node: depth + 1 entries at most
        if self.max_depth + 1 > STACK_SIZE {
            return Err(GpuError::Unsupported(format!(
                "a BVH is {} levels deep, the GPU traversal stack holds {STACK_SIZE}",
                self.max_depth
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
            bytemuck::cast_slice(&self.triangles),
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
fn supported(scene: &Scene) -> Result<(), GpuError> {
    if scene.tracer.stepper != crate::scene::Stepper::Hart {
        return Err(GpuError::Unsupported(format!(
            "tracer.stepper {:?}: the GPU traces with Hart's stepper only (use --backend cpu)",
            scene.tracer.stepper
        )));
    }
    Ok(())
}

/// Levels of the BVH2 rooted at `root` (1 for a single leaf).
fn depth_of(nodes: &[BvhNode], root: u32) -> u32 {
    let mut deepest = 0;
    let mut stack = vec![(root, 1u32)];
    while let Some((i, d)) = stack.pop() {
        deepest = deepest.max(d);
        let n = nodes[i as usize];
        if n.count == 0 {
            stack.push((n.first, d + 1));
            stack.push((n.first + 1, d + 1));
        }
    }
    deepest
}

/// The bind group layout of the scene buffers (group 0), the same for every scene.
pub fn scene_layout(ctx: &GpuContext) -> wgpu::BindGroupLayout {
    let entries: Vec<wgpu::BindGroupLayoutEntry> = scene_bindings()
        .iter()
        .enumerate()
        .map(|(i, (_, kind, _))| wgpu::BindGroupLayoutEntry {
            binding: i as u32,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: match kind {
                    BindingKind::Uniform => wgpu::BufferBindingType::Uniform,
                    BindingKind::Storage => wgpu::BufferBindingType::Storage { read_only: true },
                },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        })
        .collect();
    ctx.device
        .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("hytrace scene"),
            entries: &entries,
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
            });
        }
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("hytrace scene"),
            layout: &layout,
            entries: &entries,
        });
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use std::path::Path;

    /// A gyroid sphere (a long tape, so a deep octree pays) beside a plain sphere (whose tape is
    /// too short to split: an octree of one leaf).
    fn scene() -> Scene {
        let src = "Scene(
            camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
            objects: [
                (shape: Sphere(radius: 0.5), translate: (3, 0, 0)),
                (shape: Implicit(expr: \"max(sqrt(x*x + y*y + z*z) - 1, abs(sin(6*x)*cos(6*y) + sin(6*y)*cos(6*z) + sin(6*z)*cos(6*x)) - 0.3)\", lipschitz: 20, half_extents: (1, 1, 1))),
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
        let fields = crate::trace::build_fields(&scene, true);
        let small = fields[0]
            .octree
            .as_ref()
            .expect("every object has an octree");
        assert_eq!(small.leaves().len(), 1);
        assert!(fields[1].octree.as_ref().unwrap().leaves().len() > 1);
        let data = SceneData::from_fields(&scene, &fields).unwrap();
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

    #[test]
    fn fields_must_match_the_objects() {
        let scene = scene();
        let fields = crate::trace::build_fields(&scene, true);
        assert!(SceneData::from_fields(&scene, &fields[..1]).is_err());
    }
}
