//! Ray queries and tape evaluation on the GPU, in chunked dispatches: the GPU's side of the
//! backend-independent [`RayQuery`] interface and of the SDF conformance suite's
//! [`Evaluator`].

use super::GpuError;
use super::context::GpuContext;
use super::records::{ChunkParams, FieldProbeResult, ProbeResult, QueryRay, QueryResult};
use super::scene::{GpuScene, SceneData, scene_layout};
use super::shaders::{
    EVAL_KERNEL, FIELD_PROBE_KERNEL, HIT_MESH, HIT_SDF, KernelSource, PROBE_KERNEL, QUERY_CLOSEST,
    QUERY_KERNEL, QUERY_OCCLUDED, WORKGROUP_SIZE, layout_entries,
};
use crate::geom::Ray;
use crate::scene::Scene;
use crate::sdf::conformance::Evaluator;
use crate::sdf::tape::Tape;
use crate::trace::SceneTracer;
use crate::trace::query::{ObjectId, QueryHit, RayQuery};
use glam::Vec3;

/// Items per dispatch unless told otherwise: small enough that one dispatch of the slowest
/// kernel (SDF rays on lavapipe) stays far below a driver watchdog's seconds.
pub const DEFAULT_CHUNK: u32 = 8192;

/// What a kernel's chunks are told besides their range ([`ChunkParams`]); each kernel reads
/// its own field.
#[derive(Debug, Clone, Copy, Default)]
pub struct KernelArgs {
    /// The query kernel: `QUERY_*` bits.
    pub queries: u32,
    /// Tape evaluation and the field probe: the SDF object.
    pub object: u32,
    /// The probe kernel: the penumbra sharpness k.
    pub penumbra_k: f32,
}

/// A compute kernel over the scene library: group 0 the scene, group 1 an input array, an
/// output array and the chunk parameters.
pub struct Kernel {
    pipeline: wgpu::ComputePipeline,
    io_layout: wgpu::BindGroupLayout,
}

/// Passes of the probe kernel: surface (material, exit), soft, improved soft, distance.
const PROBE_PASSES: u32 = 4;

impl Kernel {
    /// Compiles a kernel over the scene library (once per context: later requests share the
    /// pipeline, see [`GpuContext::compute_pipeline`]).
    pub fn new(ctx: &GpuContext, kernel: &KernelSource) -> Result<Self, GpuError> {
        Self::from_source(ctx, kernel, &kernel.module())
    }

    /// Compiles `kernel` from a complete module (as [`KernelSource::module`] gives it, perhaps
    /// altered: tests check that a broken library is caught).
    pub fn from_source(
        ctx: &GpuContext,
        kernel: &KernelSource,
        source: &str,
    ) -> Result<Self, GpuError> {
        let compiled = ctx.compute_pipeline(kernel.file, source, kernel.entry, || {
            let io_layout = ctx
                .device
                .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some(kernel.file),
                    entries: &layout_entries(&kernel.io()),
                });
            vec![scene_layout(ctx), io_layout]
        })?;
        Ok(Kernel {
            pipeline: compiled.pipeline,
            io_layout: compiled.layouts[1].clone(),
        })
    }

    /// Runs the kernel over items `0..count` in dispatches of at most `chunk` items, each
    /// submitted on its own, and waits for the last.
    #[allow(clippy::too_many_arguments)]
    pub fn run(
        &self,
        ctx: &GpuContext,
        scene: &GpuScene,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        count: u32,
        chunk: u32,
        args: KernelArgs,
    ) -> Result<(), GpuError> {
        self.run_part(ctx, scene, input, output, count, chunk, args, 0)
    }

    /// [`Kernel::run`] for one pass (`part`) of a multi-pass kernel.
    #[allow(clippy::too_many_arguments)]
    pub fn run_part(
        &self,
        ctx: &GpuContext,
        scene: &GpuScene,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        count: u32,
        chunk: u32,
        args: KernelArgs,
        part: u32,
    ) -> Result<(), GpuError> {
        let chunk = chunk.clamp(1, 65535 * WORKGROUP_SIZE);
        let mut first = 0;
        while first < count {
            let n = chunk.min(count - first);
            let params = ChunkParams {
                first,
                count: n,
                part,
                queries: args.queries,
                object: args.object,
                penumbra_k: args.penumbra_k,
                ..Default::default()
            };
            let uniform = ctx.uniform_buffer("hytrace chunk", bytemuck::bytes_of(&params));
            let io = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("hytrace chunk"),
                layout: &self.io_layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: input.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: output.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: uniform.as_entire_binding(),
                    },
                ],
            });
            let mut encoder = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &scene.bind_group, &[]);
                pass.set_bind_group(1, &io, &[]);
                pass.dispatch_workgroups(n.div_ceil(WORKGROUP_SIZE), 1, 1);
            }
            ctx.queue.submit([encoder.finish()]);
            // one chunk at a time: the device never holds more than one dispatch's work
            ctx.wait()?;
            first += n;
        }
        Ok(())
    }
}

/// Ray queries against one scene on the GPU: the GPU's [`RayQuery`].
pub struct GpuQuery<'a> {
    ctx: &'a GpuContext,
    scene: GpuScene,
    kernel: Kernel,
    chunk: u32,
    objects: u32,
    /// Rays run again alone because the driver cut their work short.
    rerun: std::cell::Cell<usize>,
}

impl<'a> GpuQuery<'a> {
    /// Uploads `scene` and compiles the query kernel.
    pub fn new(ctx: &'a GpuContext, scene: &Scene) -> Result<Self, GpuError> {
        Self::from_data(ctx, &SceneData::from_scene(scene)?)
    }

    /// [`GpuQuery::new`] with a CPU tracer's acceleration structures (its field octrees and
    /// BVHs), so that the GPU walks exactly the CPU's.
    pub fn with_tracer(ctx: &'a GpuContext, tracer: &SceneTracer) -> Result<Self, GpuError> {
        Self::from_data(ctx, &SceneData::from_tracer(tracer)?)
    }

    fn from_data(ctx: &'a GpuContext, data: &SceneData) -> Result<Self, GpuError> {
        Ok(GpuQuery {
            ctx,
            scene: GpuScene::new(ctx, data)?,
            kernel: Kernel::new(ctx, &QUERY_KERNEL)?,
            chunk: DEFAULT_CHUNK,
            objects: data.objects.len() as u32,
            rerun: std::cell::Cell::new(0),
        })
    }

    /// Sets how many rays one dispatch handles (the answers do not depend on it).
    pub fn with_chunk(mut self, chunk: u32) -> Self {
        self.chunk = chunk.max(1);
        self
    }

    /// The uploaded scene.
    pub fn scene(&self) -> &GpuScene {
        &self.scene
    }

    /// How many rays [`GpuQuery::run`] and [`GpuQuery::probe`] have run again alone so far
    /// because the driver cut their work short in the batch (see `loops_were_cut` in
    /// shaders/tape.wgsl).
    pub fn rays_rerun(&self) -> usize {
        self.rerun.get()
    }

    /// Runs the query kernel over rays with per-ray intervals; `queries` is a set of
    /// `QUERY_*` bits. Fails with [`GpuError::LoopsCut`] when the
    /// driver cut some rays' work short.
    pub fn run(&self, rays: &[QueryRay], queries: u32) -> Result<Vec<QueryResult>, GpuError> {
        let args = KernelArgs {
            queries,
            ..Default::default()
        };
        let mut results: Vec<QueryResult> = self.run_kernel(&self.kernel, rays, args, 1)?;
        let still_cut =
            self.rerun_cut_alone(&self.kernel, rays, args, 1, &mut results, |r| r.cut != 0)?;
        if still_cut > 0 {
            return Err(GpuError::LoopsCut {
                count: still_cut,
                what: "rays",
            });
        }
        Ok(results)
    }

    /// Runs the probe kernel (`shaders/probe.wgsl`: material, exit, soft visibilities with
    /// sharpness `k`, distance) over rays; compiles it on each call. A ray whose work the
    /// driver cuts short even when probed alone comes back with [`ProbeResult::cut`] set.
    pub fn probe(&self, rays: &[QueryRay], k: f32) -> Result<Vec<ProbeResult>, GpuError> {
        let kernel = Kernel::new(self.ctx, &PROBE_KERNEL)?;
        // One pass per query, each its own dispatch, so that one invocation spends less of
        // llvmpipe's loop budget (see `loops_were_cut` in shaders/tape.wgsl): with all
        // queries in one invocation it ran out on glass.ron, as the render kernel did with
        // several samples per invocation.
        let args = KernelArgs {
            penumbra_k: k,
            ..Default::default()
        };
        let mut results: Vec<ProbeResult> = self.run_kernel(&kernel, rays, args, PROBE_PASSES)?;
        // those cut even alone keep `cut` set for the caller to leave out
        self.rerun_cut_alone(&kernel, rays, args, PROBE_PASSES, &mut results, |r| {
            r.cut != 0
        })?;
        Ok(results)
    }

    /// Runs the field probe kernel (`shaders/field_probe.wgsl`: the field and its leaf at
    /// each ray's origin, the leaves of the octree walk over its interval) for one object;
    /// compiles it on each call.
    pub fn field_probe(
        &self,
        rays: &[QueryRay],
        object: u32,
    ) -> Result<Vec<FieldProbeResult>, GpuError> {
        self.field_probe_source(&FIELD_PROBE_KERNEL.module(), rays, object)
    }

    /// [`GpuQuery::field_probe`] with the module compiled from `source` (the library and the
    /// field probe kernel, perhaps altered).
    pub fn field_probe_source(
        &self,
        source: &str,
        rays: &[QueryRay],
        object: u32,
    ) -> Result<Vec<FieldProbeResult>, GpuError> {
        if object >= self.objects {
            return Err(GpuError::Unsupported(format!(
                "SDF object {object} of a scene with {}",
                self.objects
            )));
        }
        let kernel = Kernel::from_source(self.ctx, &FIELD_PROBE_KERNEL, source)?;
        let args = KernelArgs {
            object,
            ..Default::default()
        };
        self.run_kernel(&kernel, rays, args, 1)
    }

    /// Runs again, one by one, the rays whose results `cut` says the driver cut short
    /// (llvmpipe's loop budget, see `loops_were_cut` in shaders/tape.wgsl: it is spent by a
    /// whole SIMD group together, and a ray alone spends only its own), each result replaced
    /// by its own run's; returns how many are cut even alone.
    fn rerun_cut_alone<T: bytemuck::Pod>(
        &self,
        kernel: &Kernel,
        rays: &[QueryRay],
        args: KernelArgs,
        passes: u32,
        results: &mut [T],
        cut: impl Fn(&T) -> bool,
    ) -> Result<usize, GpuError> {
        let mut still_cut = 0;
        for (i, result) in results.iter_mut().enumerate() {
            if cut(result) {
                self.rerun.set(self.rerun.get() + 1);
                let alone: Vec<T> = self.run_kernel(kernel, &rays[i..=i], args, passes)?;
                *result = alone[0];
                still_cut += cut(result) as usize;
            }
        }
        Ok(still_cut)
    }

    /// Runs `passes` passes of `kernel` (`chunk.part` = 0, 1, …) over the rays into one result
    /// buffer and reads it back.
    fn run_kernel<T: bytemuck::Pod>(
        &self,
        kernel: &Kernel,
        rays: &[QueryRay],
        args: KernelArgs,
        passes: u32,
    ) -> Result<Vec<T>, GpuError> {
        if rays.is_empty() {
            return Ok(Vec::new());
        }
        let count = u32::try_from(rays.len())
            .map_err(|_| GpuError::Unsupported(format!("{} rays in one batch", rays.len())))?;
        let input = self
            .ctx
            .storage_buffer("hytrace rays", bytemuck::cast_slice(rays), false);
        let size = (rays.len() * std::mem::size_of::<T>()) as u64;
        let output = self
            .ctx
            .storage_buffer("hytrace results", &vec![0u8; size as usize], true);
        for part in 0..passes {
            kernel.run_part(
                self.ctx,
                &self.scene,
                &input,
                &output,
                count,
                self.chunk,
                args,
                part,
            )?;
        }
        let bytes = self.ctx.read_buffer(&output, size)?;
        Ok(bytemuck::pod_collect_to_vec(&bytes))
    }

    fn batch(rays: &[Ray], tmin: f32, tmax: f32) -> Vec<QueryRay> {
        rays.iter()
            .map(|r| QueryRay {
                origin: r.origin.to_array(),
                tmin,
                direction: r.direction.to_array(),
                tmax,
            })
            .collect()
    }

    /// Closest hits of a batch of rays over one interval.
    pub fn closest_hits(
        &self,
        rays: &[Ray],
        tmin: f32,
        tmax: f32,
    ) -> Result<Vec<Option<QueryHit>>, GpuError> {
        Ok(self
            .run(&Self::batch(rays, tmin, tmax), QUERY_CLOSEST)?
            .iter()
            .map(to_query_hit)
            .collect())
    }

    /// Occlusion of a batch of rays over one interval.
    pub fn occluded_batch(
        &self,
        rays: &[Ray],
        tmin: f32,
        tmax: f32,
    ) -> Result<Vec<bool>, GpuError> {
        Ok(self
            .run(&Self::batch(rays, tmin, tmax), QUERY_OCCLUDED)?
            .iter()
            .map(|r| r.occluded != 0)
            .collect())
    }
}

/// A query result as the backend-independent hit.
pub fn to_query_hit(r: &QueryResult) -> Option<QueryHit> {
    let object = match r.kind {
        HIT_SDF => ObjectId::Sdf(r.object as usize),
        HIT_MESH => ObjectId::MeshInstance(r.object as usize),
        _ => return None,
    };
    Some(QueryHit {
        t: r.t,
        normal: Vec3::from(r.normal),
        object,
    })
}

impl RayQuery for GpuQuery<'_> {
    /// One ray per dispatch: correct but slow; batch with [`GpuQuery::closest_hits`].
    /// A device failure panics here (the trait has no error channel).
    fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<QueryHit> {
        self.closest_hits(std::slice::from_ref(ray), tmin, tmax)
            .unwrap_or_else(|e| panic!("GPU query failed: {e}"))[0]
    }

    fn occluded(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        self.occluded_batch(std::slice::from_ref(ray), tmin, tmax)
            .unwrap_or_else(|e| panic!("GPU query failed: {e}"))[0]
    }

    fn closest_hit_many(&self, rays: &[Ray], tmin: f32, tmax: f32) -> Vec<Option<QueryHit>> {
        self.closest_hits(rays, tmin, tmax)
            .unwrap_or_else(|e| panic!("GPU query failed: {e}"))
    }

    fn occluded_many(&self, rays: &[Ray], tmin: f32, tmax: f32) -> Vec<bool> {
        self.occluded_batch(rays, tmin, tmax)
            .unwrap_or_else(|e| panic!("GPU query failed: {e}"))
    }
}

/// Tape evaluation on the GPU: the conformance suite's [`Evaluator`] for the WGSL
/// interpreter.
pub struct GpuSdfEvaluator<'a> {
    ctx: &'a GpuContext,
    kernel: Kernel,
    chunk: u32,
}

impl<'a> GpuSdfEvaluator<'a> {
    /// Compiles the evaluation kernel.
    pub fn new(ctx: &'a GpuContext) -> Result<Self, GpuError> {
        Ok(GpuSdfEvaluator {
            ctx,
            kernel: Kernel::new(ctx, &EVAL_KERNEL)?,
            chunk: DEFAULT_CHUNK,
        })
    }

    /// Evaluates `tape` at every point.
    pub fn try_eval(&self, tape: &Tape, points: &[Vec3]) -> Result<Vec<f32>, GpuError> {
        if points.is_empty() {
            return Ok(Vec::new());
        }
        let count = u32::try_from(points.len())
            .map_err(|_| GpuError::Unsupported(format!("{} points in one batch", points.len())))?;
        let data = SceneData::from_tapes(&[tape]);
        let scene = GpuScene::new(self.ctx, &data)?;
        let p: Vec<[f32; 4]> = points.iter().map(|p| p.extend(0.0).to_array()).collect();
        let input = self
            .ctx
            .storage_buffer("hytrace points", bytemuck::cast_slice(&p), false);
        let size = (points.len() * 4) as u64;
        let output = self
            .ctx
            .storage_buffer("hytrace values", &vec![0u8; size as usize], true);
        self.kernel.run(
            self.ctx,
            &scene,
            &input,
            &output,
            count,
            self.chunk,
            KernelArgs::default(),
        )?;
        let bytes = self.ctx.read_buffer(&output, size)?;
        Ok(bytemuck::pod_collect_to_vec(&bytes))
    }
}

impl Evaluator for GpuSdfEvaluator<'_> {
    /// A device failure panics here (the trait has no error channel).
    fn eval(&self, tape: &Tape, points: &[Vec3]) -> Vec<f32> {
        self.try_eval(tape, points)
            .unwrap_or_else(|e| panic!("GPU tape evaluation failed: {e}"))
    }
}
