//! Tracing: sphere tracing of SDF objects over their specialised-tape octrees, normals, and
//! the scene's closest-hit and occlusion queries over SDF objects and triangle meshes together.

pub mod crossing;
pub mod normal;
pub mod packet;
pub mod query;
pub mod segment;
pub mod sphere;
pub mod step;

pub use step::{TraceResult, epsilon_at};

use crate::accel::bvh::BuildQuality;
use crate::accel::field::{self, FieldCursor, ObjectField};
use crate::accel::{MeshAccel, SdfAccel};
use crate::geom::{Aabb, Ray};
use crate::scene::material::MaterialParams;
use crate::scene::{Scene, SdfObject, Shadow, Stepper, TracerSettings};
use crate::sdf::tape::{MaterialVec, Registers, Tape};
use glam::Vec3;
use rayon::prelude::*;
use std::ops::ControlFlow;

/// What a ray hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Surface {
    /// An SDF object (index into `Scene::objects`).
    Sdf(usize),
    /// A triangle of a mesh instance, at barycentrics (u, v).
    Mesh {
        /// Index into `SceneMeshes::instances`.
        instance: u32,
        /// Triangle of the instance's mesh.
        triangle: u32,
        /// Barycentric weight of the second vertex.
        u: f32,
        /// Barycentric weight of the third vertex.
        v: f32,
        /// Scene material index there (found once, with the normal, at the hit).
        material: u32,
        /// What the file material's textures make of the material there.
        sample: crate::scene::meshes::SurfaceSample,
    },
}

/// The closest intersection of a ray with the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter (distance along the unit direction).
    pub t: f32,
    /// What was hit.
    pub surface: Surface,
    /// Unit surface normal: out of the solid for SDFs, as the file orients it for meshes.
    pub normal: Vec3,
    /// |∇f| at the hit as the normal estimator measured it: 1 for an exact field, below 1
    /// for a conservative bound, above 1 for a broken one (the `gradient` debug view).
    pub gradient: f32,
    /// Sphere-tracing steps spent on this ray, over all objects tried.
    pub steps: u32,
}

/// Marches from t0 towards t1 with the scene's stepper (`tracer.stepper`):
/// [`sphere::trace_hart`] by default, [`sphere::trace_relaxed`], [`sphere::trace_adaptive`] or
/// [`segment::trace_segment`] when asked for.
pub fn trace(
    field: &mut FieldCursor,
    ray: &Ray,
    t0: f32,
    t1: f32,
    s: &TracerSettings,
) -> TraceResult {
    match s.stepper {
        Stepper::Hart => sphere::trace_hart(field, ray, t0, t1, s),
        Stepper::Relaxed(omega) => sphere::trace_relaxed(field, ray, t0, t1, s, omega),
        Stepper::Adaptive => sphere::trace_adaptive(field, ray, t0, t1, s),
        Stepper::Segment => segment::trace_segment(field, ray, t0, t1, s),
    }
}

/// How to build the acceleration structures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AccelOptions {
    /// A BVH over the SDF objects' bounds (else a linear scan, the reference).
    pub sdf_bvh: bool,
    /// Build quality of the mesh BVHs.
    pub mesh_quality: BuildQuality,
    /// An octree of region-specialised tapes per SDF object (else every sample evaluates the
    /// whole tape, the reference the octree is tested against).
    pub specialise: bool,
    /// Every tape compiled to native code where the CPU runs it ([`crate::sdf::jit`]; else
    /// interpreted, which gives the same bits).
    pub native: bool,
    /// Coherent rays ([`SceneTracer::closest_hits`]) marched in SIMD packets (else one by
    /// one, which gives the same answers).
    pub packets: bool,
    /// The meshes placed once traced as one tree in world space ([`crate::accel::merge`];
    /// else each under its instance, the two-level tree it is checked against).
    pub merge_meshes: bool,
}

impl Default for AccelOptions {
    fn default() -> Self {
        AccelOptions {
            sdf_bvh: true,
            mesh_quality: BuildQuality::Medium,
            specialise: true,
            native: true,
            packets: true,
            merge_meshes: true,
        }
    }
}

/// The box an object's octree covers: the cube around its bounds, or, for an unbounded
/// object (planes, infinite repetition), its bounds with the unbounded axes clipped to the
/// scene's finite bounds grown by half their size — where the camera looks; outside the box
/// the whole tape is evaluated, which is always right.
///
/// A cube, because the octree halves every axis at once: over a flat object's own box its
/// cells are as flat, and a ray across the flat axis crosses as many of them as one along
/// the long axes would. On 400 boxes tiling a square six times wider than deep, seen face
/// on, a camera ray walked 6.6 leaves to its hit over the flat box and 2.5 over the cube; on
/// 1,000 such boxes the frame took a quarter less and the octree built in a third of the
/// time. The clipped boxes of unbounded objects stay as they are: a floor's cube would be
/// mostly empty space that every ray from the camera walks (3–5 % slower frames).
pub fn field_region(object: &SdfObject, scene_box: &Aabb) -> Aabb {
    let b = object.bounds();
    if b.is_finite() {
        if b.is_empty() {
            return b;
        }
        let half = Vec3::splat(0.5 * (b.max - b.min).max_element());
        return Aabb {
            min: b.center() - half,
            max: b.center() + half,
        };
    }
    if scene_box.is_empty() || !scene_box.is_finite() {
        return Aabb::EMPTY;
    }
    let grow = 0.5 * (scene_box.max - scene_box.min).max_element() + 1.0;
    b.intersection(&scene_box.expand(grow))
}

/// Builds every object's field (in parallel over objects; each octree builds in parallel too),
/// its tapes compiled to native code if `native`.
pub fn build_fields(scene: &Scene, specialise: bool, native: bool) -> Vec<ObjectField> {
    let scene_box = scene.finite_bounds();
    let shares = budget_shares(scene);
    let keep = trees_to_keep(scene);
    let mut fields: Vec<ObjectField> = scene
        .objects
        .par_iter()
        .zip(&shares)
        .map(|(o, &share)| {
            let l = &o.lowered;
            if specialise {
                ObjectField::build_shared(l, field_region(o, &scene_box), share, keep)
            } else {
                ObjectField::whole(&l.distance, &l.shading)
            }
        })
        .collect();
    if native {
        crate::accel::field::compile_native(&mut fields, &shares);
    }
    fields
}

/// Which field octrees the scene's build keeps: every one, unless the scene holds more than
/// [`field::MANY_MARCHED_WHOLE`] objects whose trees Hart's march might take whole (tapes of
/// [`field::MIN_SPLIT_TAPE`] to [`field::SHORT_TAPE`] instructions); then those it walks.
fn trees_to_keep(scene: &Scene) -> field::Keep {
    let range = field::MIN_SPLIT_TAPE..=field::SHORT_TAPE;
    let candidates = scene
        .objects
        .par_iter()
        .filter(|o| range.contains(&o.lowered.program.distance_only().live_len()))
        .count();
    if candidates > field::MANY_MARCHED_WHOLE {
        field::Keep::Walked
    } else {
        field::Keep::Every
    }
}

/// Each object's share of an object's budgets for its field ([`ObjectField::build_shared`]):
/// 1 for an object of the file, and for the parts of an object split into several
/// ([`crate::scene::Part`]), their shares of it in proportion to their tapes.
fn budget_shares(scene: &Scene) -> Vec<f64> {
    let mut shares = vec![1.0; scene.objects.len()];
    let mut first = 0;
    while first < scene.objects.len() {
        let count = scene.objects[first].part.map_or(1, |p| p.count);
        let parts = &scene.objects[first..(first + count).min(scene.objects.len())];
        if count > 1 {
            let total: usize = parts.iter().map(|o| o.lowered.distance.len().max(1)).sum();
            for (k, o) in parts.iter().enumerate() {
                shares[first + k] = o.lowered.distance.len().max(1) as f64 / total as f64;
            }
        }
        first += parts.len();
    }
    shares
}

/// Answers ray queries against a scene's SDF objects and meshes on the CPU.
pub struct SceneTracer<'a> {
    scene: &'a Scene,
    accel: SdfAccel,
    meshes: MeshAccel,
    fields: Vec<ObjectField>,
    field_build_time: std::time::Duration,
    packets: bool,
}

/// A [`SceneTracer`]'s acceleration structures without the scene (see
/// [`SceneTracer::into_parts`]).
pub struct TracerParts {
    accel: SdfAccel,
    meshes: MeshAccel,
    fields: Vec<ObjectField>,
    field_build_time: std::time::Duration,
    packets: bool,
}

thread_local! {
    /// Packet scratch (8 KiB of SIMD registers) kept per thread.
    static PACKET_SCRATCH: std::cell::RefCell<packet::PacketScratch> =
        std::cell::RefCell::new(packet::PacketScratch::new());
}

impl<'a> SceneTracer<'a> {
    /// Prepares the acceleration structures: an SDF BVH, and mesh BVHs of the scene's
    /// `tracer.bvh` quality.
    pub fn new(scene: &'a Scene) -> Self {
        Self::with_options(
            scene,
            AccelOptions {
                mesh_quality: scene.tracer.bvh,
                ..Default::default()
            },
        )
    }

    /// Prepares the acceleration structures.
    pub fn with_options(scene: &'a Scene, options: AccelOptions) -> Self {
        let start = std::time::Instant::now();
        let fields = build_fields(scene, options.specialise, options.native);
        let field_build_time = start.elapsed();
        SceneTracer {
            scene,
            accel: if options.sdf_bvh {
                SdfAccel::new(&scene.objects)
            } else {
                SdfAccel::linear(&scene.objects)
            },
            meshes: MeshAccel::with_merging(
                &scene.meshes,
                options.mesh_quality,
                options.merge_meshes,
            ),
            fields,
            field_build_time,
            packets: options.packets,
        }
    }

    /// Takes the acceleration structures off the scene they were built for, to trace the
    /// same objects and meshes under other settings ([`SceneTracer::with_parts`]) without
    /// building them again.
    pub fn into_parts(self) -> TracerParts {
        TracerParts {
            accel: self.accel,
            meshes: self.meshes,
            fields: self.fields,
            field_build_time: self.field_build_time,
            packets: self.packets,
        }
    }

    /// A tracer over `scene` with structures built for a scene of the same objects and
    /// meshes; only its settings (stepper, shadows, occlusion, shading) may differ.
    ///
    /// # Panics
    /// When the object count differs from the one the structures were built for.
    pub fn with_parts(scene: &'a Scene, parts: TracerParts) -> Self {
        assert_eq!(
            scene.objects.len(),
            parts.fields.len(),
            "tracer structures of another scene"
        );
        SceneTracer {
            scene,
            accel: parts.accel,
            meshes: parts.meshes,
            fields: parts.fields,
            field_build_time: parts.field_build_time,
            packets: parts.packets,
        }
    }

    /// The SDF objects' fields (octrees of specialised tapes), in scene order.
    pub fn fields(&self) -> &[ObjectField] {
        &self.fields
    }

    /// Wall-clock time spent building the fields.
    pub fn field_build_time(&self) -> std::time::Duration {
        self.field_build_time
    }

    /// A cursor over object i's field.
    pub fn cursor<'r>(&self, object: usize, regs: &'r mut Registers) -> FieldCursor<'_, 'r> {
        self.fields[object].cursor(regs)
    }

    /// The SDF objects' acceleration structure.
    pub fn sdf_accel(&self) -> &SdfAccel {
        &self.accel
    }

    /// The meshes' acceleration structure.
    pub fn mesh_accel(&self) -> &MeshAccel {
        &self.meshes
    }

    /// The scene being traced.
    pub fn scene(&self) -> &Scene {
        self.scene
    }

    /// The closest hit in (tmin, tmax) over meshes and SDFs, with its normal. Meshes are
    /// tried first: their hit (cheap to find) shortens every SDF object's march.
    pub fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<Hit> {
        let limit = tmax.min(self.scene.tracer.max_distance);
        let mesh_hit = if self.meshes.is_empty() {
            None
        } else {
            self.meshes.tlas.closest_hit_filtered(
                &self.meshes.blas,
                ray,
                tmin,
                limit,
                &self.meshes.alpha_test(&self.scene.meshes),
            )
        };
        self.closest_hit_after_meshes(ray, tmin, limit, mesh_hit)
    }

    /// [`Self::closest_hit`] of every ray, into `out`: the same answers, with the mesh hits of
    /// coherent neighbours (a row of a render tile) found by one packet walk
    /// ([`crate::accel::bvh::InstanceBvh::closest_hits`]).
    ///
    /// # Panics
    /// When `rays` and `out` differ in length.
    pub fn closest_hits(&self, rays: &[Ray], tmin: f32, tmax: f32, out: &mut [Option<Hit>]) {
        assert_eq!(rays.len(), out.len());
        let limit = tmax.min(self.scene.tracer.max_distance);
        let mut mesh_hits = vec![None; rays.len()];
        if !self.meshes.is_empty() {
            let limits = vec![limit; rays.len()];
            self.meshes.tlas.closest_hits_filtered(
                &self.meshes.blas,
                rays,
                tmin,
                &limits,
                &mut mesh_hits,
                &self.meshes.alpha_test(&self.scene.meshes),
            );
        }
        if self.scene.tracer.stepper != Stepper::Hart || !self.packets {
            for ((ray, mesh_hit), out) in rays.iter().zip(mesh_hits).zip(out) {
                *out = self.closest_hit_after_meshes(ray, tmin, limit, mesh_hit);
            }
            return;
        }
        PACKET_SCRATCH.with(|scratch| {
            self.sdf_hits_in_packets(
                rays,
                tmin,
                limit,
                &mesh_hits,
                &mut scratch.borrow_mut(),
                out,
            )
        });
    }

    /// The SDF part of [`Self::closest_hits`] with Hart's stepper, rays marched in packets of
    /// eight per object ([`packet::trace_hart_packet`]). Every ray visits its objects in the
    /// order its own BVH walk would, each within the limit its nearer hits leave (the walk's
    /// pruning, applied to the list of every object its bounds reach), so each ray's answer is
    /// the one [`Self::closest_hit`] gives it.
    fn sdf_hits_in_packets(
        &self,
        rays: &[Ray],
        tmin: f32,
        limit: f32,
        mesh_hits: &[Option<crate::accel::bvh::InstanceHit>],
        scratch: &mut packet::PacketScratch,
        out: &mut [Option<Hit>],
    ) {
        let s = &self.scene.tracer;
        let n = rays.len();
        let mut limits: Vec<f32> = mesh_hits
            .iter()
            .map(|h| h.as_ref().map_or(limit, |h| h.t))
            .collect();
        let mut candidates = Candidates::new(&self.accel, rays, tmin, &limits);
        let mut best: Vec<Option<(f32, usize)>> = vec![None; n];
        let mut steps = vec![0u32; n];
        let mut pending = Vec::with_capacity(n);
        let mut lanes = Vec::with_capacity(packet::BUNDLE);
        let mut results = [TraceResult::of_points(None, 0); packet::BUNDLE];
        // the walk's pruning: an object whose bounds start past the ray's nearest hit so far
        while candidates.round(|r, t0| t0 <= limits[r], &mut pending) {
            for group in pending.chunk_by(|a, b| a.0 == b.0) {
                let object = group[0].0;
                for chunk in group.chunks(packet::BUNDLE) {
                    lanes.clear();
                    lanes.extend(chunk.iter().map(|&(_, r, t0, t1)| packet::Lane {
                        ray: rays[r],
                        t0,
                        t1: t1.min(limits[r]),
                    }));
                    let res = &mut results[..lanes.len()];
                    packet::trace_hart_packet(&self.fields[object], &lanes, s, scratch, res);
                    for (&(_, r, _, _), res) in chunk.iter().zip(res.iter()) {
                        steps[r] += res.steps;
                        if let Some(t) = res.t {
                            best[r] = Some((t, object));
                            limits[r] = t;
                        }
                    }
                }
            }
        }
        let mut regs = Registers::pooled();
        for r in 0..n {
            self.finish_hit(
                &rays[r],
                best[r],
                steps[r],
                mesh_hits[r],
                &mut regs,
                &mut out[r],
            );
        }
    }

    /// The rest of [`Self::closest_hit`] once the meshes' closest hit within `[tmin, limit]`
    /// is known: the SDF objects nearer than it, and the hit's surface.
    fn closest_hit_after_meshes(
        &self,
        ray: &Ray,
        tmin: f32,
        mut limit: f32,
        mesh_hit: Option<crate::accel::bvh::InstanceHit>,
    ) -> Option<Hit> {
        let s = &self.scene.tracer;
        if let Some(h) = &mesh_hit {
            limit = h.t;
        }
        let mut regs = Registers::pooled();
        let mut best: Option<(f32, usize)> = None;
        let mut steps = 0;
        self.accel.visit(ray, tmin, &mut limit, |i, t0, t1, limit| {
            let r = trace(&mut self.fields[i].cursor(&mut regs), ray, t0, t1, s);
            steps += r.steps;
            // the march stays within [t0, t1] ⊆ [tmin, limit]: any hit is the nearest so far
            if let Some(t) = r.t {
                best = Some((t, i));
                *limit = t;
            }
            ControlFlow::Continue(())
        });
        let mut hit = None;
        self.finish_hit(ray, best, steps, mesh_hit, &mut regs, &mut hit);
        hit
    }

    /// The hit a closest-hit query reports: the nearest SDF hit with its normal, else the
    /// mesh hit with its surface; written to `out` (returned by value, the hit was copied
    /// into the caller's slot in wider words than it was written in, before those stores
    /// could forward: a stall on every ray of a bundle).
    fn finish_hit(
        &self,
        ray: &Ray,
        best: Option<(f32, usize)>,
        steps: u32,
        mesh_hit: Option<crate::accel::bvh::InstanceHit>,
        regs: &mut Registers,
        out: &mut Option<Hit>,
    ) {
        let s = &self.scene.tracer;
        if let Some((t, object)) = best {
            let p = ray.at(t);
            let h = normal::step_for(s, t, p);
            let mut field = self.fields[object].cursor(regs);
            let (n, gradient) = normal::estimate(&mut field, p, h, s.normals);
            *out = Some(Hit {
                t,
                surface: Surface::Sdf(object),
                normal: n,
                gradient,
                steps,
            });
            return;
        }
        *out = mesh_hit.map(|h| {
            let surf =
                self.scene
                    .meshes
                    .surface(h.instance as usize, h.triangle as usize, h.u, h.v);
            Hit {
                t: h.t,
                surface: Surface::Mesh {
                    instance: h.instance,
                    triangle: h.triangle,
                    u: h.u,
                    v: h.v,
                    material: surf.material,
                    sample: surf.sample,
                },
                normal: surf.normal,
                gradient: 1.0,
                steps,
            }
        });
    }

    /// The fraction of light arriving along a shadow ray over (tmin, tmax): 0 or 1 for hard
    /// shadows, the penumbra estimate for soft ones. The penumbra of the scene (the minimum
    /// of the objects' fields) is the minimum of the objects' penumbrae, since min over t of
    /// k·min_i(h_i)/t = min over i of min over t of k·h_i/t.
    pub fn visibility(&self, ray: &Ray, tmin: f32, tmax: f32, shadow: Shadow) -> f32 {
        let (k, improved) = match shadow {
            Shadow::None => return 1.0,
            Shadow::Hard => {
                return if self.occluded(ray, tmin, tmax) {
                    0.0
                } else {
                    1.0
                };
            }
            // Meshes have no distance field to estimate a penumbra from: they block or not.
            _ if self.mesh_blocks(ray, tmin, tmax) => return 0.0,
            Shadow::Soft(k) => (k, false),
            Shadow::SoftImproved(k) => (k, true),
        };
        let s = &self.scene.tracer;
        let mut regs = Registers::pooled();
        let mut res: f32 = 1.0;
        let mut limit = tmax.min(s.max_distance);
        // k·h/t < 1 only where h < t/k ≤ limit/k: objects farther than that from the ray
        // cannot darken it, nearer ones can even when the ray misses their bounds.
        let margin = limit / k;
        self.accel
            .visit_within(ray, tmin, &mut limit, margin, |i, t0, t1, _| {
                // the penumbra counts distance from the shadow ray's origin, not from the bounds
                let mut field = self.fields[i].cursor(&mut regs);
                let v = sphere::penumbra(&mut field, ray, t0, t1, s, k, improved);
                res = res.min(v);
                if res <= 0.0 {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            });
        // Quilez smooths the estimate with smoothstep to hide its piecewise-linear falloff.
        res * res * (3.0 - 2.0 * res)
    }

    /// [`Self::visibility`] of every query, into `out`: the same values, with coherent
    /// queries (the shadow rays of a tile row toward one light) marched in SIMD packets, each
    /// ray visiting its objects in its own BVH order.
    ///
    /// # Panics
    /// When `queries` and `out` differ in length.
    pub fn visibilities(&self, queries: &[ShadowQuery], out: &mut [f32]) {
        assert_eq!(queries.len(), out.len());
        let s = &self.scene.tracer;
        if s.stepper != Stepper::Hart || !self.packets {
            for (q, o) in queries.iter().zip(out.iter_mut()) {
                *o = self.visibility(&q.ray, q.tmin, q.tmax, q.shadow);
            }
            return;
        }
        PACKET_SCRATCH.with(|scratch| {
            let scratch = &mut *scratch.borrow_mut();
            // queries of one shadow kind together, in their order
            let mut order: Vec<usize> = (0..queries.len()).collect();
            order.sort_by_key(|&i| shadow_key(queries[i].shadow));
            for kind in order
                .chunk_by(|&a, &b| shadow_key(queries[a].shadow) == shadow_key(queries[b].shadow))
            {
                match queries[kind[0]].shadow {
                    Shadow::None => kind.iter().for_each(|&i| out[i] = 1.0),
                    Shadow::Hard => self.hard_in_packets(queries, kind, scratch, out),
                    Shadow::Soft(k) => self.soft_in_packets(queries, kind, k, false, scratch, out),
                    Shadow::SoftImproved(k) => {
                        self.soft_in_packets(queries, kind, k, true, scratch, out)
                    }
                }
            }
        });
    }

    /// Hard shadows of `which` queries: blocked by a mesh, or by the first object whose
    /// march hits (any order gives the same answer: no limit shrinks).
    fn hard_in_packets(
        &self,
        queries: &[ShadowQuery],
        which: &[usize],
        scratch: &mut packet::PacketScratch,
        out: &mut [f32],
    ) {
        let s = &self.scene.tracer;
        let (rays, tmins, limits) = gathered(queries, which, s.max_distance);
        let mut blocked = self.meshes_block(&rays, &tmins, &limits);
        // objects a ray provably passes (a ground plane it leaves) are no lanes
        let mut candidates = self.shadow_candidates(
            &rays,
            &tmins,
            &limits,
            |_| 0.0,
            |field, ray, t0, t1, regs| sphere::misses_from_start(field, ray, t0, t1, s, regs),
        );
        let mut results = [TraceResult::of_points(None, 0); packet::BUNDLE];
        candidates.in_packets(
            &rays,
            &mut blocked,
            |blocked, r| !blocked[r],
            |blocked, object, lanes, which| {
                let res = &mut results[..lanes.len()];
                packet::trace_hart_packet(&self.fields[object], lanes, s, scratch, res);
                for (&r, res) in which.iter().zip(res.iter()) {
                    blocked[r] |= res.t.is_some();
                }
            },
        );
        for (k, &i) in which.iter().enumerate() {
            out[i] = if blocked[k] { 0.0 } else { 1.0 };
        }
    }

    /// The candidates of a batch of shadow rays, leaving out the (ray, object) pairs that
    /// `told(field, ray, t0, t1, registers)` answers without a march.
    fn shadow_candidates(
        &self,
        rays: &[Ray],
        tmins: &[f32],
        limits: &[f32],
        margin: impl Fn(usize) -> f32,
        told: impl Fn(&ObjectField, &Ray, f32, f32, &mut Registers) -> bool,
    ) -> Candidates {
        let mut regs = Registers::pooled();
        Candidates::of_shadow_rays(&self.accel, rays, tmins, limits, margin, |r, i, t0, t1| {
            told(&self.fields[i], &rays[r], t0, t1, &mut regs)
        })
    }

    /// Soft shadows of `which` queries (all of penumbra sharpness k): blocked by a mesh, else
    /// the minimum over the objects near the ray of their penumbrae, smoothed.
    #[allow(clippy::too_many_arguments)]
    fn soft_in_packets(
        &self,
        queries: &[ShadowQuery],
        which: &[usize],
        k: f32,
        improved: bool,
        scratch: &mut packet::PacketScratch,
        out: &mut [f32],
    ) {
        let s = &self.scene.tracer;
        let (rays, tmins, limits) = gathered(queries, which, s.max_distance);
        let mut res: Vec<f32> = self
            .meshes_block(&rays, &tmins, &limits)
            .into_iter()
            .map(|blocked| if blocked { 0.0 } else { 1.0 })
            .collect();
        // k·h/t < 1 only where h < t/k ≤ limit/k: objects farther than that cannot darken;
        // those whose penumbra provably leaves a ray lit (a ground plane it leaves) are no
        // lanes
        let mut candidates = self.shadow_candidates(
            &rays,
            &tmins,
            &limits,
            |r| limits[r] / k,
            |field, ray, t0, t1, regs| sphere::unshaded_from_start(field, ray, t0, t1, k, s, regs),
        );
        let mut values = [0.0f32; packet::BUNDLE];
        candidates.in_packets(
            &rays,
            &mut res,
            |res, r| res[r] > 0.0,
            |res, object, lanes, which| {
                let v = &mut values[..lanes.len()];
                packet::penumbra_packet(&self.fields[object], lanes, s, k, improved, scratch, v);
                for (&r, v) in which.iter().zip(v.iter()) {
                    res[r] = res[r].min(*v);
                }
            },
        );
        for (k, &i) in which.iter().enumerate() {
            let r = res[k];
            // Quilez smooths the estimate with smoothstep to hide its piecewise-linear falloff
            out[i] = if r <= 0.0 {
                0.0
            } else {
                r * r * (3.0 - 2.0 * r)
            };
        }
    }

    /// The scene's distance field at p (the minimum over objects), clamped to `reach`: only
    /// objects whose bounds grown by `reach` contain p are evaluated — found through the
    /// acceleration structure with a zero-length ray, so ambient occlusion costs the same with
    /// ten objects or ten thousand — and every other object is at least `reach` away.
    pub fn distance(&self, p: Vec3, reach: f32) -> f32 {
        let mut regs = Registers::pooled();
        let mut d = reach;
        let probe = Ray {
            origin: p,
            direction: Vec3::Y,
        };
        let mut tmax = 0.0;
        self.accel
            .visit_within(&probe, 0.0, &mut tmax, reach, |i, _, _, _| {
                d = d.min(self.fields[i].cursor(&mut regs).eval(p));
                ControlFlow::Continue(())
            });
        d
    }

    /// [`Self::distance`] at every point, clamped to `reach`, into `out`: the same values.
    /// The (point, object) pairs are grouped by the tape valid at the point and evaluated
    /// eight at a time on SIMD lanes. (Ambient occlusion asks five or so distances at every
    /// shaded pixel; one at a time, through the interpreter, they were 27 % of shadows.ron's
    /// frame.)
    pub fn distances(&self, points: &[Vec3], reach: f32, out: &mut [f32]) {
        assert_eq!(points.len(), out.len());
        out.fill(reach);
        let mut regs = Registers::pooled();
        // (the tape's address, the point, the tape) of every object near every point
        let mut pairs: Vec<(usize, usize, &Tape)> = Vec::new();
        for (k, &p) in points.iter().enumerate() {
            let probe = Ray {
                origin: p,
                direction: Vec3::Y,
            };
            let mut tmax = 0.0;
            self.accel
                .visit_within(&probe, 0.0, &mut tmax, reach, |i, _, _, _| {
                    let tape = self.fields[i].cursor(&mut regs).tape_at(p);
                    pairs.push((tape as *const Tape as usize, k, tape));
                    ControlFlow::Continue(())
                });
        }
        if pairs.is_empty() {
            return;
        }
        pairs.sort_unstable_by_key(|&(tape, k, _)| (tape, k));
        PACKET_SCRATCH.with(|scratch| {
            let scratch = &mut *scratch.borrow_mut();
            for group in pairs.chunk_by(|a, b| a.0 == b.0) {
                for lanes in group.chunks(packet::PACKET) {
                    let (_, first, tape) = lanes[0];
                    // the lanes past the group's points repeat its first
                    let at: [Vec3; packet::PACKET] =
                        std::array::from_fn(|j| points[lanes.get(j).map_or(first, |l| l.1)]);
                    let xyz = [at.map(|p| p.x), at.map(|p| p.y), at.map(|p| p.z)];
                    let d = scratch.eval8(tape, &xyz);
                    // the least over the objects, in any order: a NaN is dropped by min, and
                    // only a zero's sign may depend on the order
                    for (&(_, k, _), &d) in lanes.iter().zip(&d) {
                        out[k] = out[k].min(d);
                    }
                }
            }
        });
    }

    /// The material at a hit: the SDF's blended material from its shading tape, or the mesh
    /// triangle's material with its textures applied. `materials` is the scene's
    /// table as the tapes expect it.
    pub fn material_at(&self, hit: &Hit, p: Vec3, materials: &[MaterialVec]) -> MaterialParams {
        match hit.surface {
            Surface::Sdf(object) => {
                let field = &self.fields[object];
                // one material over the whole object: no leaf to find
                let tape = if field.whole_shading.has_constant_material() {
                    &field.whole_shading
                } else {
                    field.shading_at(p)
                };
                MaterialParams::from_vec(&tape.material_at(p, materials))
            }
            Surface::Mesh {
                material, sample, ..
            } => sample.apply(self.scene.materials[material as usize]),
        }
    }

    /// The hits among `hits` (of `rays`) whose material a shading tape blends at the point
    /// (a checkerboard's tiles), with [`Self::material_at`] there (the same bits), in
    /// increasing `i`, into `out` (cleared first). They are evaluated eight at a time,
    /// grouped by tape, on SIMD lanes. (Interpreted one hit at a time, antialiasing.ron's
    /// checkerboard spent 45 % of its frame there, glass.ron 20 %.)
    pub fn blended_materials(
        &self,
        rays: &[Ray],
        hits: &[Option<Hit>],
        materials: &[MaterialVec],
        out: &mut Vec<(usize, MaterialParams)>,
    ) {
        out.clear();
        // (the tape's address, the hit) of the hits with a blended material
        let mut blended: Vec<(usize, usize)> = Vec::new();
        for (i, (ray, hit)) in rays.iter().zip(hits).enumerate() {
            let Some(Hit {
                surface: Surface::Sdf(object),
                t,
                ..
            }) = *hit
            else {
                continue;
            };
            let field = &self.fields[object];
            if field.whole_shading.has_constant_material() {
                continue;
            }
            let tape = field.shading_at(ray.at(t));
            if !tape.has_constant_material() {
                blended.push((tape as *const Tape as usize, i));
            }
        }
        if blended.is_empty() {
            return;
        }
        let point = |i: usize| rays[i].at(hits[i].as_ref().map_or(0.0, |h| h.t));
        // one tape's hits together
        blended.sort_unstable();
        PACKET_SCRATCH.with(|scratch| {
            let scratch = &mut *scratch.borrow_mut();
            for group in blended.chunk_by(|a, b| a.0 == b.0) {
                for lanes in group.chunks(packet::PACKET) {
                    let (_, first) = lanes[0];
                    let Some(Surface::Sdf(object)) = hits[first].as_ref().map(|h| h.surface) else {
                        unreachable!("only SDF hits are blended");
                    };
                    let tape = self.fields[object].shading_at(point(first));
                    // the lanes past the group's hits repeat its first point
                    let at: [Vec3; packet::PACKET] =
                        std::array::from_fn(|k| point(lanes.get(k).map_or(first, |l| l.1)));
                    let xyz = [at.map(|p| p.x), at.map(|p| p.y), at.map(|p| p.z)];
                    let m = scratch.material8(tape, &xyz, materials);
                    for (k, &(_, i)) in lanes.iter().enumerate() {
                        let v: MaterialVec = std::array::from_fn(|f| m[f][k]);
                        out.push((i, MaterialParams::from_vec(&v)));
                    }
                }
            }
        });
        out.sort_unstable_by_key(|&(i, _)| i);
    }

    /// Whether a mesh blocks the ray within (tmin, tmax).
    /// [`Self::mesh_blocks`] of each ray over `[tmins[k], limits[k]]` (limits already within
    /// `max_distance`). Rays that share one `tmin` — the renderer's shadow rays all start at
    /// 0 — go through the instance BVH's packet any-hit walk, which traces coherent neighbours
    /// (a tile row's shadow rays towards one light) together and gives the same answers.
    fn meshes_block(&self, rays: &[Ray], tmins: &[f32], limits: &[f32]) -> Vec<bool> {
        let mut blocked = vec![false; rays.len()];
        if self.meshes.is_empty() || rays.is_empty() {
            return blocked;
        }
        if tmins.iter().all(|t| t.to_bits() == tmins[0].to_bits()) {
            self.meshes.tlas.any_hits_filtered(
                &self.meshes.blas,
                rays,
                tmins[0],
                limits,
                &mut blocked,
                &self.meshes.alpha_test(&self.scene.meshes),
            );
        } else {
            for (k, b) in blocked.iter_mut().enumerate() {
                *b = self.mesh_blocks(&rays[k], tmins[k], limits[k]);
            }
        }
        blocked
    }

    fn mesh_blocks(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        !self.meshes.is_empty()
            && self.meshes.tlas.any_hit_filtered(
                &self.meshes.blas,
                ray,
                tmin,
                tmax.min(self.scene.tracer.max_distance),
                &self.meshes.alpha_test(&self.scene.meshes),
            )
    }

    /// The distance at which a ray that starts inside the solid `surface` belongs to leaves
    /// it, with the outward normal there. For a mesh, the solid is bounded by the meshes: the
    /// next mesh surface along the ray is the exit.
    pub fn exit(&self, surface: Surface, ray: &Ray, tmax: f32) -> Option<(f32, Vec3)> {
        let s = &self.scene.tracer;
        let object = match surface {
            Surface::Sdf(object) => object,
            Surface::Mesh { .. } => {
                let h = self.meshes.tlas.closest_hit_filtered(
                    &self.meshes.blas,
                    ray,
                    0.0,
                    tmax.min(s.max_distance),
                    &self.meshes.alpha_test(&self.scene.meshes),
                )?;
                let n = self
                    .scene
                    .meshes
                    .surface(h.instance as usize, h.triangle as usize, h.u, h.v)
                    .normal;
                // leaving the solid: the outward normal points along the ray
                return Some((h.t, if n.dot(ray.direction) < 0.0 { -n } else { n }));
            }
        };
        let mut regs = Registers::pooled();
        let mut field = self.fields[object].cursor(&mut regs);
        let t = sphere::exit(&mut field, ray, 0.0, tmax.min(s.max_distance), s)?;
        let p = ray.at(t);
        let n = normal::estimate(&mut field, p, normal::step_for(s, t, p), s.normals).0;
        Some((t, n))
    }

    /// Whether anything blocks the ray within (tmin, tmax) (shadow rays): stops at the first
    /// object hit, in any order.
    pub fn occluded(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        if self.mesh_blocks(ray, tmin, tmax) {
            return true;
        }
        let s = &self.scene.tracer;
        let mut regs = Registers::pooled();
        let mut blocked = false;
        let mut limit = tmax.min(s.max_distance);
        self.accel.visit(ray, tmin, &mut limit, |i, t0, t1, _| {
            if trace(&mut self.fields[i].cursor(&mut regs), ray, t0, t1, s)
                .t
                .is_some()
            {
                blocked = true;
                return ControlFlow::Break(());
            }
            ControlFlow::Continue(())
        });
        blocked
    }
}

/// A shadow ray for [`SceneTracer::visibilities`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadowQuery {
    /// The ray toward the light.
    pub ray: Ray,
    /// Start of the interval.
    pub tmin: f32,
    /// End (the light's distance).
    pub tmax: f32,
    /// What kind of shadow the light casts.
    pub shadow: Shadow,
}

/// A key that groups queries of one shadow kind and sharpness.
fn shadow_key(s: Shadow) -> (u8, u32) {
    match s {
        Shadow::None => (0, 0),
        Shadow::Hard => (1, 0),
        Shadow::Soft(k) => (2, k.to_bits()),
        Shadow::SoftImproved(k) => (3, k.to_bits()),
    }
}

/// Every ray's SDF objects in the order its own BVH walk visits them (with the interval its
/// bounds give), taken a round at a time: the next object of each ray still marching, so that
/// the rays at one object are marched as packets while each keeps its own order. (Shadow rays
/// take their objects from [`SdfAccel::visit_rays_within`], nearest entry first: a shadow's
/// answer does not depend on the order, while a closest hit's march is bounded by the hits
/// before it, and a hit confirmed near that bound may differ in its last bits.)
struct Candidates {
    starts: Vec<usize>,
    items: Vec<(usize, f32, f32)>,
    next: Vec<usize>,
}

impl Candidates {
    /// The candidates of closest-hit rays, each ray's in its own walk's order.
    fn new(accel: &SdfAccel, rays: &[Ray], tmin: f32, limits: &[f32]) -> Self {
        let mut c = Self::empty(rays.len());
        for (r, ray) in rays.iter().enumerate() {
            c.starts.push(c.items.len());
            c.next.push(c.items.len());
            let mut limit = limits[r];
            accel.visit_within(ray, tmin, &mut limit, 0.0, |i, t0, t1, _| {
                c.items.push((i, t0, t1));
                ControlFlow::Continue(())
            });
        }
        c.starts.push(c.items.len());
        c
    }

    fn empty(rays: usize) -> Self {
        Candidates {
            starts: Vec::with_capacity(rays + 1),
            items: Vec::new(),
            next: Vec::with_capacity(rays),
        }
    }

    /// The candidates of shadow rays (whose answers do not depend on the order of their
    /// objects), leaving out those `passed(ray, object, t0, t1)` settles.
    fn of_shadow_rays(
        accel: &SdfAccel,
        rays: &[Ray],
        tmins: &[f32],
        limits: &[f32],
        margin: impl Fn(usize) -> f32,
        mut passed: impl FnMut(usize, usize, f32, f32) -> bool,
    ) -> Self {
        let mut c = Self::empty(rays.len());
        // the rays come ray after ray: each ray's list starts where the items stand when its
        // first object (or the next ray's) comes
        accel.visit_rays_within(rays, tmins, limits, margin, |r, i, t0, t1| {
            while c.starts.len() <= r {
                c.starts.push(c.items.len());
                c.next.push(c.items.len());
            }
            if !passed(r, i, t0, t1) {
                c.items.push((i, t0, t1));
            }
        });
        while c.starts.len() < rays.len() {
            c.starts.push(c.items.len());
            c.next.push(c.items.len());
        }
        c.starts.push(c.items.len());
        c
    }

    /// Fills `pending` with (object, ray, t0, t1) for the next object of every ray for which
    /// `keep(ray, t0)` holds (objects it refuses are passed over, as the walk prunes them),
    /// sorted by object; false when none is left.
    fn round(
        &mut self,
        keep: impl Fn(usize, f32) -> bool,
        pending: &mut Vec<(usize, usize, f32, f32)>,
    ) -> bool {
        pending.clear();
        for r in 0..self.next.len() {
            while self.next[r] < self.starts[r + 1] {
                let (i, t0, t1) = self.items[self.next[r]];
                self.next[r] += 1;
                if keep(r, t0) {
                    pending.push((i, r, t0, t1));
                    break;
                }
            }
        }
        // a ray has at most one entry per round, so the keys differ: any sort gives one order
        pending.sort_unstable_by_key(|&(i, r, _, _)| (i, r));
        !pending.is_empty()
    }

    /// Marches the candidates round after round while `keep(state, ray)` holds: each round's
    /// (object, ray) pairs are grouped by object into bundles of at most [`packet::BUNDLE`]
    /// lanes and handed to `visit(state, object, lanes, rays of the lanes)`.
    fn in_packets<S: ?Sized>(
        &mut self,
        rays: &[Ray],
        state: &mut S,
        keep: impl Fn(&S, usize) -> bool,
        mut visit: impl FnMut(&mut S, usize, &[packet::Lane], &[usize]),
    ) {
        let mut pending = Vec::new();
        let mut lanes = Vec::with_capacity(packet::BUNDLE);
        let mut lane_rays = Vec::with_capacity(packet::BUNDLE);
        while self.round(|r, _| keep(state, r), &mut pending) {
            for group in pending.chunk_by(|a, b| a.0 == b.0) {
                for chunk in group.chunks(packet::BUNDLE) {
                    lanes.clear();
                    lane_rays.clear();
                    for &(_, r, t0, t1) in chunk {
                        lanes.push(packet::Lane {
                            ray: rays[r],
                            t0,
                            t1,
                        });
                        lane_rays.push(r);
                    }
                    visit(state, group[0].0, &lanes, &lane_rays);
                }
            }
        }
    }
}

/// The rays, start distances and limits (clamped to the tracer's range) of `which` queries,
/// gathered for a batched walk.
fn gathered(
    queries: &[ShadowQuery],
    which: &[usize],
    max_distance: f32,
) -> (Vec<Ray>, Vec<f32>, Vec<f32>) {
    let rays = which.iter().map(|&i| queries[i].ray).collect();
    let tmins = which.iter().map(|&i| queries[i].tmin).collect();
    let limits = which
        .iter()
        .map(|&i| queries[i].tmax.min(max_distance))
        .collect();
    (rays, tmins, limits)
}
