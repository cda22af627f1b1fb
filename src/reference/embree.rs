//! Intel Embree 4 as the referee: a scene's meshes and analytic SDF primitives as an Embree
//! scene, answering the same [`RayQuery`] as our CPU tracer.
//!
//! Built through raw `embree4_sys` calls, with small RAII wrappers that release the device, the
//! scenes and the geometries, and a ray-hit record sized for the library we actually link
//! (`RayHit`: the 4.4 library writes a field the 4.2 bindings do not have).
//!
//! * **Meshes**: each mesh of [`SceneMeshes::meshes`](crate::scene::SceneMeshes) becomes one
//!   Embree scene holding a triangle geometry, built once; each instance is an
//!   `RTC_GEOMETRY_TYPE_INSTANCE` of it in the top-level scene, with the instance's object→world
//!   transform (`RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR`). Embree reports the hit in the instance's
//!   object space; the normal returned is the triangle's geometric normal (counter-clockwise
//!   front, as the files orient it) under the instance's normal matrix. Meshes with glTF
//!   alpha masks (`MASK` materials) get intersect and occluded filter functions
//!   (`rtcSetGeometryIntersectFilterFunction`) that reject hits on the masks' holes with the
//!   tracer's own test ([`SceneMeshes::masked_out`](crate::scene::SceneMeshes::masked_out)),
//!   so masked surfaces are compared as the tracer sees them. The meshes placed only once are
//!   merged as the tracer merges them ([`MergedMeshes`]): one triangle geometry of their
//!   world-space vertices (the same `f32` values), instanced with the identity; its hits are
//!   reported as hits on the instances' own triangles.
//! * **SDF objects** whose tree is one analytic primitive (Sphere, Box, Plane, Torus, Cylinder,
//!   Cone, Capsule, Ellipsoid) under any nesting of `Transform` (rotation, uniform scale,
//!   translation) and `Material` nodes become `RTC_GEOMETRY_TYPE_USER` geometries. Their
//!   intersect and occluded callbacks map the ray into object space with the inverse transform
//!   in f64 — without renormalising the direction, so t stays a world-space distance — and
//!   call the matching [`analytic`] function, honouring the ray's `(tnear, tfar)`.
//! * **Planes** are unbounded; Embree needs finite bounds, so a plane is clipped to a cube: the
//!   bounds of every finite object, every mesh instance and the camera position, grown by twice
//!   the tracer's `max_distance` on every side. Every ray that starts in the scene's bounds and
//!   stops at `max_distance` (as the CPU tracer's rays do) sees the same plane as the tracer.
//! * **Every other SDF object** (CSG, smooth operators, rounding, onion, non-uniform `Scale`,
//!   domain operators, twist/bend, implicits, and the primitives without a closed-form
//!   intersector: RoundBox, Octahedron, HexPrism, …) is by default a user geometry too, whose
//!   callbacks find the first root of its distance tape along the ray by certified interval
//!   bisection in f64 ([`certified`], over [`interval64`]'s outward-rounded enclosures): the
//!   root is enclosed within δ ([`certified_search`]: ε₀/64), the search is confined to the
//!   object's bounds (an unbounded object's cut by the planes' clip box), the normal is the
//!   tape's gradient, and a search that runs out of interval evaluations answers "no hit" and
//!   is counted ([`EmbreeScene::uncertified`]) — [`SdfCheck::Certified`].
//! * With [`ReferenceOptions::meshed`] (`validate --meshed`) such
//!   objects are meshed instead, from their distance tape by
//!   [`mesher`] (marching cubes, vertices refined onto the surface) into a world-space triangle
//!   geometry, in a scene of its own of MEDIUM build quality instanced with the identity; its
//!   [`SdfCheck::Meshed`] states the resolution and the tolerance: every mesh point lies within
//!   `tolerance` = h·(1 + w) of the true surface, h the cell size and w ≤ 10⁻³ the widest root
//!   bracket of the vertex refinement (see [`mesher`] for why). The normal returned is the
//!   triangle's outward face normal. Unbounded meshed objects (infinite repetition) are meshed
//!   only inside a clip box ([`ReferenceOptions::mesh_clip`]); the mesh is open at the box's
//!   faces, so it adds no walls, and [`EmbreeScene::mesh_region`] tells a comparison where the mesh stands for the
//!   object: a ray whose true hit on such an object lies outside that box has no counterpart
//!   in Embree and must be left out of a comparison.
//! * An object is [`SdfCheck::Skipped`] only if the mesher refuses it (bounds that are NaN),
//!   with the reason.

mod packet;

pub use packet::PacketWidth;

use super::analytic::{self, AnalyticHit};
use super::certified::{self, Root, Search};
use super::interval64::{self, Program, Registers as IntervalRegisters};
use super::mesher::{self, MeshOptions, SdfMesh};
use crate::accel::merge::{MergedMeshes, own_tree_needed};
use crate::geom::{Aabb, Ray};
use crate::scene::Scene;
use crate::sdf::SdfNode;
use crate::sdf::lower::transform_of;
use crate::sdf::tape::Tape;
use crate::trace::query::{ObjectId, QueryHit, RayQuery};
use embree4_sys::{
    RTC_INVALID_GEOMETRY_ID, RTCBounds, RTCBoundsFunctionArguments, RTCBufferType, RTCBuildQuality,
    RTCDevice, RTCError, RTCFormat, RTCGeometry, RTCGeometryType, RTCHit,
    RTCIntersectFunctionNArguments, RTCOccludedFunctionNArguments, RTCRay, RTCRayHit, RTCScene,
    RTCSceneFlags,
};
use glam::{Affine3A, DAffine3, DMat3, DVec3, Mat3A, Vec3};
use rayon::prelude::*;
use std::cell::RefCell;
use std::ffi::c_void;
use std::ptr;
use std::sync::atomic::{AtomicU64, Ordering};

/// An Embree device, released on drop.
struct Device(RTCDevice);

impl Device {
    fn new() -> Result<Self, String> {
        // SAFETY: the config string is NUL-terminated (a C string literal).
        let d = unsafe { embree4_sys::rtcNewDevice(c"verbose=0".as_ptr()) };
        if d.is_null() {
            Err("rtcNewDevice failed".into())
        } else {
            Ok(Device(d))
        }
    }

    fn check(&self, what: &str) -> Result<(), String> {
        // SAFETY: the device is alive.
        let e = unsafe { embree4_sys::rtcGetDeviceError(self.0) };
        if e == RTCError::NONE {
            Ok(())
        } else {
            Err(format!("Embree error {e:?} after {what}"))
        }
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: created by rtcNewDevice, released once.
        unsafe { embree4_sys::rtcReleaseDevice(self.0) }
    }
}

/// An Embree scene, released on drop.
struct SceneHandle(RTCScene);

impl SceneHandle {
    fn with_quality(
        device: &Device,
        quality: RTCBuildQuality,
        robust: bool,
    ) -> Result<Self, String> {
        // SAFETY: the device is alive.
        let s = unsafe { embree4_sys::rtcNewScene(device.0) };
        if s.is_null() {
            return Err("rtcNewScene failed".into());
        }
        // SAFETY: a fresh scene.
        unsafe {
            embree4_sys::rtcSetSceneBuildQuality(s, quality);
            // A referee must be watertight: Embree's default triangle test lets rays through
            // shared edges (seen on ReciprocatingSaw: hits 2.6 units behind an edge our
            // watertight test catches); ROBUST mode makes its traversal and test watertight.
            // Only the benchmark turns it off, to time Embree at its fastest.
            if robust {
                embree4_sys::rtcSetSceneFlags(s, RTCSceneFlags::ROBUST);
            }
        }
        Ok(SceneHandle(s))
    }

    /// Attaches the geometry (the scene takes its own reference) and returns its ID.
    fn attach(&self, geometry: &Geometry) -> u32 {
        // SAFETY: both handles are alive; the geometry is committed.
        unsafe { embree4_sys::rtcAttachGeometry(self.0, geometry.0) }
    }

    fn commit(&self) {
        // SAFETY: the scene is alive and every attached geometry is committed.
        unsafe { embree4_sys::rtcCommitScene(self.0) }
    }
}

impl Drop for SceneHandle {
    fn drop(&mut self) {
        // SAFETY: created by rtcNewScene, released once.
        unsafe { embree4_sys::rtcReleaseScene(self.0) }
    }
}

/// An Embree geometry (our reference to it), released on drop; a scene it is attached to
/// keeps its own reference.
struct Geometry(RTCGeometry);

impl Geometry {
    fn new(device: &Device, kind: RTCGeometryType) -> Result<Self, String> {
        // SAFETY: the device is alive.
        let g = unsafe { embree4_sys::rtcNewGeometry(device.0, kind) };
        if g.is_null() {
            Err(format!("rtcNewGeometry({kind:?}) failed"))
        } else {
            Ok(Geometry(g))
        }
    }

    fn commit(&self) {
        // SAFETY: the geometry is alive and fully set up.
        unsafe { embree4_sys::rtcCommitGeometry(self.0) }
    }
}

impl Drop for Geometry {
    fn drop(&mut self) {
        // SAFETY: created by rtcNewGeometry, our reference is released once.
        unsafe { embree4_sys::rtcReleaseGeometry(self.0) }
    }
}

/// A closed-form primitive in its object space, with the parameters of its SDF node.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Primitive {
    Sphere(f64),
    Cuboid(DVec3),
    Plane {
        normal: DVec3,
        offset: f64,
    },
    Torus {
        major: f64,
        minor: f64,
    },
    Cylinder {
        half_height: f64,
        radius: f64,
    },
    Cone {
        half_height: f64,
        bottom: f64,
        top: f64,
    },
    Capsule {
        a: DVec3,
        b: DVec3,
        radius: f64,
    },
    Ellipsoid(DVec3),
}

impl Primitive {
    fn intersect(&self, ro: DVec3, rd: DVec3, tmin: f64, tmax: f64) -> Option<AnalyticHit> {
        match *self {
            Primitive::Sphere(r) => analytic::sphere(ro, rd, r, tmin, tmax),
            Primitive::Cuboid(h) => analytic::box_(ro, rd, h, tmin, tmax),
            Primitive::Plane { normal, offset } => {
                analytic::plane(ro, rd, normal, offset, tmin, tmax)
            }
            Primitive::Torus { major, minor } => analytic::torus(ro, rd, major, minor, tmin, tmax),
            Primitive::Cylinder {
                half_height,
                radius,
            } => analytic::capped_cylinder(ro, rd, half_height, radius, tmin, tmax),
            Primitive::Cone {
                half_height,
                bottom,
                top,
            } => analytic::capped_cone(ro, rd, half_height, bottom, top, tmin, tmax),
            Primitive::Capsule { a, b, radius } => {
                analytic::capsule(ro, rd, a, b, radius, tmin, tmax)
            }
            Primitive::Ellipsoid(r) => analytic::ellipsoid(ro, rd, r, tmin, tmax),
        }
    }

    /// Object-space bounds, or `None` for the unbounded plane.
    fn bounds(&self) -> Option<(DVec3, DVec3)> {
        let sym = |h: DVec3| Some((-h, h));
        match *self {
            Primitive::Sphere(r) => sym(DVec3::splat(r)),
            Primitive::Cuboid(h) => sym(h),
            Primitive::Plane { .. } => None,
            Primitive::Torus { major, minor } => {
                sym(DVec3::new(major + minor, minor, major + minor))
            }
            Primitive::Cylinder {
                half_height,
                radius,
            } => sym(DVec3::new(radius, half_height, radius)),
            Primitive::Cone {
                half_height,
                bottom,
                top,
            } => {
                let r = bottom.max(top);
                sym(DVec3::new(r, half_height, r))
            }
            Primitive::Capsule { a, b, radius } => Some((
                a.min(b) - DVec3::splat(radius),
                a.max(b) + DVec3::splat(radius),
            )),
            Primitive::Ellipsoid(r) => sym(r),
        }
    }
}

/// The user data of one SDF user geometry; boxed, so its address is stable for Embree.
struct UserShape {
    primitive: Primitive,
    /// World → object.
    to_object: DAffine3,
    /// Maps object-space normals to world space (the inverse transpose of object → world).
    normal_to_world: DMat3,
    /// World bounds reported to Embree (and, for a plane, the clip box of its hits).
    bounds: RTCBounds,
    /// Whether hits outside `bounds` are dropped (planes only).
    clip: bool,
}

/// The user data of an SDF object without a closed form: its tape, intersected by the
/// certified first-root search ([`certified::first_crossing`]).
struct CertifiedShape {
    /// The tape's value instructions for interval evaluation.
    program: Program,
    /// The tape itself, for the normal at a hit.
    tape: Tape,
    search: Search,
    /// The searched box (world, f64) and its f32 form for Embree.
    lo: DVec3,
    hi: DVec3,
    bounds: RTCBounds,
    /// Searches that ran out of boxes.
    uncertified: AtomicU64,
}

thread_local! {
    /// Interval registers of the certified search on this thread (Embree calls back on the
    /// thread that traces).
    static INTERVAL_REGISTERS: RefCell<Box<IntervalRegisters>> = RefCell::new(interval64::registers());
}

impl UserGeometry for CertifiedShape {
    fn bounds(&self) -> RTCBounds {
        self.bounds
    }

    fn intersect(&self, ray: &RTCRay) -> Option<(f32, Vec3)> {
        let (o, d) = origin_direction(ray);
        // Only the stretch inside the searched box (Kay & Kajiya's slabs): outside it the
        // object has no surface.
        let (mut a, mut b) = (ray.tnear as f64, ray.tfar as f64);
        for k in 0..3 {
            if d[k] == 0.0 {
                if o[k] < self.lo[k] || o[k] > self.hi[k] {
                    return None;
                }
            } else {
                let (t0, t1) = ((self.lo[k] - o[k]) / d[k], (self.hi[k] - o[k]) / d[k]);
                a = a.max(t0.min(t1));
                b = b.min(t0.max(t1));
            }
        }
        if a.is_nan() || b.is_nan() || a > b {
            return None;
        }
        let root = INTERVAL_REGISTERS.with(|r| {
            certified::first_crossing(&self.program, o, d, a, b, &self.search, &mut r.borrow_mut())
        });
        let c = match root {
            Root::Crossing(c) => c,
            Root::None { .. } => return None,
            Root::Uncertified => {
                self.uncertified.fetch_add(1, Ordering::Relaxed);
                return None;
            }
        };
        let t = (0.5 * (c.lo + c.hi)) as f32;
        // f64 → f32 rounding must not carry t out of Embree's interval.
        if !(t >= ray.tnear && t <= ray.tfar) {
            return None;
        }
        let p = (o + 0.5 * (c.lo + c.hi) * d).as_vec3();
        // The field's gradient (central differences over a step well above f32 rounding at p)
        // is the surface normal: its direction only sets the |n·d| of the tolerances.
        let h = 1e-4 * (1.0 + p.abs().max_element());
        let n = self.tape.gradient(p, h).normalize_or_zero();
        Some((t, n))
    }
}

/// An Embree ray's origin and direction in f64.
fn origin_direction(ray: &RTCRay) -> (DVec3, DVec3) {
    (
        DVec3::new(ray.org_x as f64, ray.org_y as f64, ray.org_z as f64),
        DVec3::new(ray.dir_x as f64, ray.dir_y as f64, ray.dir_z as f64),
    )
}

/// What the callbacks of a user geometry ask of its user data.
trait UserGeometry {
    /// World bounds reported to Embree.
    fn bounds(&self) -> RTCBounds;
    /// The hit of a world-space Embree ray within its (tnear, tfar), as (t, unit world
    /// normal).
    fn intersect(&self, ray: &RTCRay) -> Option<(f32, Vec3)>;
}

impl UserGeometry for UserShape {
    fn bounds(&self) -> RTCBounds {
        self.bounds
    }

    fn intersect(&self, ray: &RTCRay) -> Option<(f32, Vec3)> {
        let (ro, rd) = origin_direction(ray);
        let (tnear, tfar) = (ray.tnear as f64, ray.tfar as f64);
        let ro_o = self.to_object.transform_point3(ro);
        let rd_o = self.to_object.transform_vector3(rd);
        let h = self.primitive.intersect(ro_o, rd_o, tnear, tfar)?;
        let t = h.t as f32;
        // f64 → f32 rounding must not carry t out of Embree's interval.
        if !(t >= ray.tnear && t <= ray.tfar) {
            return None;
        }
        if self.clip {
            let p = ro + h.t * rd;
            let b = &self.bounds;
            let inside = p.x >= b.lower_x as f64
                && p.y >= b.lower_y as f64
                && p.z >= b.lower_z as f64
                && p.x <= b.upper_x as f64
                && p.y <= b.upper_y as f64
                && p.z <= b.upper_z as f64;
            if !inside {
                return None;
            }
        }
        let n = (self.normal_to_world * h.normal).normalize_or_zero();
        Some((t, n.as_vec3()))
    }
}

unsafe extern "C" fn user_bounds<S: UserGeometry>(args: *const RTCBoundsFunctionArguments) {
    // SAFETY: Embree passes valid arguments; the user pointer is the `S` we set, alive as long
    // as the scene.
    unsafe {
        let args = &*args;
        let shape = &*(args.geometryUserPtr as *const S);
        *args.bounds_o = shape.bounds();
    }
}

/// `RTCRayHit` as the Embree library we link lays it out. Embree 4.3 added
/// `RTCHit::instPrimID[RTC_MAX_INSTANCE_LEVEL_COUNT]` after `instID`, present when the library
/// is built with instance arrays (`RTC_GEOMETRY_INSTANCE_ARRAY`, on in the embreex wheel's
/// Embree 4.4). embree4-sys's bindings come from the 4.2 headers, whose `RTCHit` ends at
/// `instID`: on every hit inside an instance the library writes `instPrimID[0]` four bytes
/// past the end of a 4.2 `RTCRayHit`, over whatever the caller keeps there (found as a
/// corrupted stack pointer in a benchmark probe). The tail gives that write a place of its
/// own; a 4.2 library never touches it.
#[repr(C, align(16))]
struct RayHit {
    ray_hit: RTCRayHit,
    /// `instPrimID[0]` of a 4.3+ `RTCHit`, then the padding to its 16-byte alignment.
    inst_prim_id: [u32; 4],
}

// The layout the comment above relies on: the 4.2 hit is exactly 32 bytes and the ray hit 80,
// so `inst_prim_id` starts where a 4.3+ library puts `instPrimID[0]`.
const _: () = assert!(size_of::<RTCHit>() == 32 && size_of::<RTCRayHit>() == 80);
const _: () = assert!(std::mem::offset_of!(RayHit, inst_prim_id) == 80);

unsafe extern "C" fn user_intersect<S: UserGeometry>(args: *const RTCIntersectFunctionNArguments) {
    // SAFETY: as for `user_bounds`; we only trace with rtcIntersect1, so N == 1 and `rayhit`
    // points at one RTCRayHit (checked, not assumed).
    unsafe {
        let args = &*args;
        if args.N != 1 || *args.valid == 0 {
            return;
        }
        let shape = &*(args.geometryUserPtr as *const S);
        let rayhit = &mut *(args.rayhit as *mut RTCRayHit);
        if let Some((t, n)) = shape.intersect(&rayhit.ray) {
            rayhit.ray.tfar = t;
            rayhit.hit = RTCHit {
                Ng_x: n.x,
                Ng_y: n.y,
                Ng_z: n.z,
                u: 0.0,
                v: 0.0,
                primID: args.primID,
                geomID: args.geomID,
                instID: [(*args.context).instID[0]],
            };
            // A 4.3+ library's record also has `instPrimID` (see `RayHit`); it is left as the
            // caller set it (invalid: this crate makes no instance arrays) and never read.
        }
    }
}

unsafe extern "C" fn user_occluded<S: UserGeometry>(args: *const RTCOccludedFunctionNArguments) {
    // SAFETY: as for `user_intersect`, with one RTCRay.
    unsafe {
        let args = &*args;
        if args.N != 1 || *args.valid == 0 {
            return;
        }
        let shape = &*(args.geometryUserPtr as *const S);
        let ray = &mut *(args.ray as *mut RTCRay);
        if shape.intersect(ray).is_some() {
            // Embree's mark for an occluded ray.
            ray.tfar = f32::NEG_INFINITY;
        }
    }
}

/// The primitive of an SDF tree that is one analytic primitive under rigid/uniform-scale
/// transforms and material wrappers, with its object → world map; else why not.
fn analytic_form(node: &SdfNode) -> Result<(Affine3A, Primitive), String> {
    let mut m = Affine3A::IDENTITY;
    let mut node = node;
    loop {
        node = match node {
            SdfNode::Transform { shape, .. } => {
                m *= transform_of(node).0;
                shape
            }
            SdfNode::Material { shape, .. } => shape,
            _ => break,
        };
    }
    let d = |v: Vec3| v.as_dvec3();
    let p = match node {
        SdfNode::Sphere { radius } => Primitive::Sphere(radius.0 as f64),
        SdfNode::Cuboid { half_extents } => Primitive::Cuboid(d(half_extents.0)),
        SdfNode::Plane { normal, offset } => Primitive::Plane {
            normal: d(normal.0),
            offset: offset.0 as f64,
        },
        SdfNode::Torus { major, minor } => Primitive::Torus {
            major: major.0 as f64,
            minor: minor.0 as f64,
        },
        SdfNode::Cylinder {
            half_height,
            radius,
        } => Primitive::Cylinder {
            half_height: half_height.0 as f64,
            radius: radius.0 as f64,
        },
        SdfNode::Cone {
            half_height,
            bottom_radius,
            top_radius,
        } => Primitive::Cone {
            half_height: half_height.0 as f64,
            bottom: bottom_radius.0 as f64,
            top: top_radius.0 as f64,
        },
        SdfNode::Capsule { a, b, radius } => Primitive::Capsule {
            a: d(a.0),
            b: d(b.0),
            radius: radius.0 as f64,
        },
        SdfNode::Ellipsoid { radii } => Primitive::Ellipsoid(d(radii.0)),
        other => {
            let dbg = format!("{other:?}");
            let name: String = dbg.chars().take_while(|c| c.is_alphanumeric()).collect();
            return Err(format!(
                "{name} is not an analytic primitive under rigid/uniform-scale transforms"
            ));
        }
    };
    Ok((m, p))
}

fn daffine(m: &Affine3A) -> DAffine3 {
    DAffine3::from_cols(
        Vec3::from(m.matrix3.x_axis).as_dvec3(),
        Vec3::from(m.matrix3.y_axis).as_dvec3(),
        Vec3::from(m.matrix3.z_axis).as_dvec3(),
        Vec3::from(m.translation).as_dvec3(),
    )
}

fn rtc_bounds(lo: Vec3, hi: Vec3) -> RTCBounds {
    RTCBounds {
        lower_x: lo.x,
        lower_y: lo.y,
        lower_z: lo.z,
        align0: 0.0,
        upper_x: hi.x,
        upper_y: hi.y,
        upper_z: hi.z,
        align1: 0.0,
    }
}

/// A committed Embree triangle geometry of `positions` and `triangles`.
fn triangle_geometry(
    device: &Device,
    positions: &[Vec3],
    triangles: &[[u32; 3]],
) -> Result<Geometry, String> {
    let g = Geometry::new(device, RTCGeometryType::TRIANGLE)?;
    // SAFETY: each buffer is the one Embree just allocated with the size asked for.
    unsafe {
        let v = embree4_sys::rtcSetNewGeometryBuffer(
            g.0,
            RTCBufferType::VERTEX,
            0,
            RTCFormat::FLOAT3,
            3 * size_of::<f32>(),
            positions.len(),
        ) as *mut f32;
        if v.is_null() {
            return Err("vertex buffer allocation failed".into());
        }
        for (i, p) in positions.iter().enumerate() {
            v.add(3 * i)
                .copy_from_nonoverlapping(p.to_array().as_ptr(), 3);
        }
        let ix = embree4_sys::rtcSetNewGeometryBuffer(
            g.0,
            RTCBufferType::INDEX,
            0,
            RTCFormat::UINT3,
            3 * size_of::<u32>(),
            triangles.len(),
        ) as *mut u32;
        if ix.is_null() {
            return Err("index buffer allocation failed".into());
        }
        for (i, t) in triangles.iter().enumerate() {
            ix.add(3 * i).copy_from_nonoverlapping(t.as_ptr(), 3);
        }
    }
    g.commit();
    device.check("building a triangle geometry")?;
    Ok(g)
}

/// The scene's alpha masks for the mesh geometries' filter functions: a copy of the scene's
/// meshes (Embree calls back with no borrow to tie them to) and the map from top-level
/// geometry IDs to scene instances.
struct AlphaFilter {
    meshes: crate::scene::SceneMeshes,
    /// Top-level geometry ID → scene instance.
    instance_of: Vec<u32>,
    /// Meshes some instance of which is alpha-tested.
    masked_meshes: Vec<usize>,
}

impl AlphaFilter {
    /// The filter of `meshes`, or `None` when no instance has an alpha mask.
    fn of(meshes: &crate::scene::SceneMeshes) -> Option<Box<AlphaFilter>> {
        let mut masked_meshes: Vec<usize> = (0..meshes.instances.len())
            .filter(|&i| meshes.alpha_tested(i))
            .map(|i| meshes.instances[i].mesh)
            .collect();
        masked_meshes.sort_unstable();
        masked_meshes.dedup();
        (!masked_meshes.is_empty()).then(|| {
            Box::new(AlphaFilter {
                meshes: meshes.clone(),
                instance_of: Vec::new(),
                masked_meshes,
            })
        })
    }

    /// Sets the filter functions of a mesh geometry (committed again by the caller).
    fn attach(&mut self, g: &Geometry) {
        let user = self as *mut AlphaFilter as *mut c_void;
        // SAFETY: the filter is boxed and kept by the `EmbreeScene` as long as the geometry.
        unsafe {
            embree4_sys::rtcSetGeometryUserData(g.0, user);
            embree4_sys::rtcSetGeometryIntersectFilterFunction(g.0, Some(alpha_filter));
            embree4_sys::rtcSetGeometryOccludedFilterFunction(g.0, Some(alpha_filter));
        }
    }

    fn set_instance(&mut self, top_id: u32, instance: u32) {
        let i = top_id as usize;
        if self.instance_of.len() <= i {
            self.instance_of.resize(i + 1, u32::MAX);
        }
        self.instance_of[i] = instance;
    }
}

/// The intersect and occluded filter of alpha-masked meshes: a hit on a hole of the mask is
/// rejected (`valid` cleared), so Embree goes on as if the triangle were not there.
unsafe extern "C" fn alpha_filter(args: *const embree4_sys::RTCFilterFunctionNArguments) {
    // SAFETY: Embree passes valid arguments; the user pointer is the boxed `AlphaFilter`.
    let args = unsafe { &*args };
    let filter = unsafe { &*(args.geometryUserPtr as *const AlphaFilter) };
    let n = args.N as usize;
    // RTCHitN is structure-of-arrays: Ng_x, Ng_y, Ng_z, u, v, primID, geomID, instID[0], …
    // each N 4-byte lanes long (rtcore_ray.h)
    let hit = args.hit as *const u32;
    for i in 0..n {
        // SAFETY: `valid` and the hit's lanes have N entries.
        let valid = unsafe { &mut *args.valid.add(i) };
        if *valid == 0 {
            continue;
        }
        let lane = |field: usize| unsafe { *hit.add(field * n + i) };
        let (u, v) = (f32::from_bits(lane(3)), f32::from_bits(lane(4)));
        let (triangle, top) = (lane(5), lane(7));
        let Some(&instance) = filter.instance_of.get(top as usize) else {
            continue;
        };
        if instance != u32::MAX
            && filter
                .meshes
                .masked_out(instance as usize, triangle as usize, u, v)
        {
            *valid = 0;
        }
    }
}

/// A committed user geometry of one primitive whose callbacks are `S`'s; the caller keeps
/// `shape` (boxed) alive as long as the scene.
fn user_geometry<S: UserGeometry>(device: &Device, shape: &S) -> Result<Geometry, String> {
    let g = Geometry::new(device, RTCGeometryType::USER)?;
    let user = shape as *const S as *mut c_void;
    // SAFETY: the geometry is fresh; the user data outlives the scene (the caller's promise).
    unsafe {
        embree4_sys::rtcSetGeometryUserPrimitiveCount(g.0, 1);
        embree4_sys::rtcSetGeometryUserData(g.0, user);
        embree4_sys::rtcSetGeometryBoundsFunction(g.0, Some(user_bounds::<S>), ptr::null_mut());
        embree4_sys::rtcSetGeometryIntersectFunction(g.0, Some(user_intersect::<S>));
        embree4_sys::rtcSetGeometryOccludedFunction(g.0, Some(user_occluded::<S>));
    }
    g.commit();
    Ok(g)
}

/// A committed instance of the committed scene `scene` under the object → world map `m`. The
/// scene must outlive every scene the instance is attached to.
fn instance(device: &Device, scene: &SceneHandle, m: &Affine3A) -> Result<Geometry, String> {
    let g = Geometry::new(device, RTCGeometryType::INSTANCE)?;
    let mut cols = [0f32; 12];
    cols[0..3].copy_from_slice(&m.matrix3.x_axis.to_array());
    cols[3..6].copy_from_slice(&m.matrix3.y_axis.to_array());
    cols[6..9].copy_from_slice(&m.matrix3.z_axis.to_array());
    cols[9..12].copy_from_slice(&m.translation.to_array());
    // SAFETY: the instanced scene is committed and, as the caller ensures, outlives the
    // top-level scene (field order); the matrix is 12 floats in the format named.
    unsafe {
        embree4_sys::rtcSetGeometryInstancedScene(g.0, scene.0);
        embree4_sys::rtcSetGeometryTransform(
            g.0,
            0,
            RTCFormat::FLOAT3X4_COLUMN_MAJOR,
            cols.as_ptr() as *const c_void,
        );
    }
    g.commit();
    Ok(g)
}

/// The outward unit normal of each triangle of an SDF mesh (counter-clockwise seen from
/// outside).
fn face_normals_of(mesh: &SdfMesh) -> Vec<Vec3> {
    mesh.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            (b - a).cross(c - a).normalize_or_zero()
        })
        .collect()
}

/// A scene's meshes and SDF objects (closed-form or meshed) as a committed Embree 4 scene.
pub struct EmbreeScene {
    // Field order is drop order: the top-level scene goes first (it references the mesh scenes
    // and the user data), the device last.
    top: SceneHandle,
    _mesh_scenes: Vec<SceneHandle>,
    // Boxed so that each address Embree holds stays put while the Vec grows.
    #[allow(clippy::vec_box)]
    _shapes: Vec<Box<UserShape>>,
    #[allow(clippy::vec_box)]
    certified: Vec<Box<CertifiedShape>>,
    /// The alpha masks the mesh geometries' filter functions read (boxed: Embree holds its
    /// address), when any instance has one.
    _alpha: Option<Box<AlphaFilter>>,
    device: Device,
    /// Top-level geometry ID → what it is.
    ids: Vec<Option<ObjectId>>,
    /// The merged meshes' top-level geometry ID and, per triangle, the scene instance and
    /// triangle it stands for.
    merged: Option<(u32, Vec<(u32, u32)>)>,
    /// Per mesh, the unnormalised counter-clockwise face normal of each triangle.
    face_normals: Vec<Vec<Vec3>>,
    /// Per instance: (mesh, normal matrix).
    instances: Vec<(usize, Mat3A)>,
    /// Per SDF object: the outward unit normal of each triangle of its mesh (empty unless
    /// meshed).
    sdf_face_normals: Vec<Vec<Vec3>>,
    /// Per SDF object: the box its mesh covers, if meshed.
    mesh_regions: Vec<Option<MeshRegion>>,
    /// How each SDF object (index into `Scene::objects`) is represented in the Embree scene.
    pub checks: Vec<SdfCheck>,
}

/// Where a meshed SDF object's mesh stands for its surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshRegion {
    /// The box the mesher's grid covers.
    pub bounds: Aabb,
    /// Whether the object's surface extends outside `bounds` (an unbounded object clipped):
    /// hits of the true surface outside `bounds` have no counterpart in the Embree scene.
    pub clipped: bool,
}

/// How the referee is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReferenceOptions {
    /// Grid cells along the longest side of each meshed object's box; the tolerance of a mesh
    /// is about one cell.
    pub mesh_resolution: u32,
    /// Most triangles per meshed object: above it the object is meshed again at a lower
    /// resolution (and a larger tolerance).
    pub mesh_max_triangles: usize,
    /// The box unbounded meshed objects are clipped to; `None`: the bounds of every finite
    /// SDF object, every mesh instance, the camera and the finite axes of partly unbounded
    /// objects, grown by a tenth of their diagonal (at least one unit) on every side.
    pub mesh_clip: Option<Aabb>,
    /// Whether SDF objects without a closed form are meshed (the cross-check of `validate
    /// --meshed`) instead of intersected by the certified root search.
    pub meshed: bool,
    /// The certified search's δ and work bound; `None`: [`certified_search`] of the scene's
    /// tracer settings.
    pub search: Option<Search>,
    /// Embree's ROBUST scene flag (watertight traversal and triangle test). On for a referee;
    /// the benchmark also times Embree without it, its fastest mode.
    pub robust: bool,
    /// Build quality of the top-level scene and the mesh scenes.
    pub quality: EmbreeQuality,
}

/// Embree's scene build quality (`RTCBuildQuality`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum EmbreeQuality {
    /// `RTC_BUILD_QUALITY_LOW`: a Morton build.
    Low,
    /// `RTC_BUILD_QUALITY_MEDIUM`: binned SAH, Embree's default.
    Medium,
    /// `RTC_BUILD_QUALITY_HIGH`: binned SAH with spatial splits. Only in Embree's default mode:
    /// with the ROBUST flag, Embree 4 builds the plain binned-SAH tree (its `STATIC` builder
    /// of `Triangle4v` leaves) whatever the quality asked, which is why its robust HIGH build
    /// takes as long as a default MEDIUM one.
    High,
}

impl EmbreeQuality {
    fn rtc(self) -> RTCBuildQuality {
        match self {
            EmbreeQuality::Low => RTCBuildQuality::LOW,
            EmbreeQuality::Medium => RTCBuildQuality::MEDIUM,
            EmbreeQuality::High => RTCBuildQuality::HIGH,
        }
    }
}

impl Default for ReferenceOptions {
    fn default() -> Self {
        ReferenceOptions {
            mesh_resolution: DEFAULT_MESH_RESOLUTION,
            mesh_max_triangles: DEFAULT_MESH_MAX_TRIANGLES,
            mesh_clip: None,
            meshed: false,
            search: None,
            robust: true,
            quality: EmbreeQuality::High,
        }
    }
}

pub use super::certified::{MAX_BOXES, certified_search};

/// Default [`ReferenceOptions::mesh_resolution`].
pub const DEFAULT_MESH_RESOLUTION: u32 = 128;
/// Default [`ReferenceOptions::mesh_max_triangles`].
pub const DEFAULT_MESH_MAX_TRIANGLES: usize = 1_000_000;

pub use super::check::SdfCheck;

impl EmbreeScene {
    /// Certified searches that ran out of boxes so far (each counted once per query; their
    /// rays were answered "no hit" by that object, which a comparison must not trust).
    pub fn uncertified(&self) -> u64 {
        self.certified
            .iter()
            .map(|c| c.uncertified.load(Ordering::Relaxed))
            .sum()
    }

    /// The box the mesh of SDF object `object` covers, if it was meshed.
    pub fn mesh_region(&self, object: usize) -> Option<MeshRegion> {
        self.mesh_regions.get(object).copied().flatten()
    }

    /// SDF objects left out of the Embree scene: (index into `Scene::objects`, why).
    pub fn skipped(&self) -> Vec<(usize, &str)> {
        self.checks
            .iter()
            .enumerate()
            .filter_map(|(i, c)| match c {
                SdfCheck::Skipped { why } => Some((i, why.as_str())),
                _ => None,
            })
            .collect()
    }
}

// SAFETY: after the commit, Embree allows concurrent rtcIntersect1/rtcOccluded1 calls on a
// scene from any thread; our user data is immutable.
unsafe impl Send for EmbreeScene {}
// SAFETY: as above; `&self` methods only trace.
unsafe impl Sync for EmbreeScene {}

impl EmbreeScene {
    /// Builds (and commits, build quality HIGH) the Embree scene of `scene` with the default
    /// [`ReferenceOptions`].
    pub fn build(scene: &Scene) -> Result<EmbreeScene, String> {
        Self::build_with(scene, &ReferenceOptions::default())
    }

    /// Builds (and commits) the Embree scene of `scene`.
    pub fn build_with(scene: &Scene, options: &ReferenceOptions) -> Result<EmbreeScene, String> {
        let device = Device::new()?;
        let quality = options.quality.rtc();
        let top = SceneHandle::with_quality(&device, quality, options.robust)?;
        let mut ids: Vec<Option<ObjectId>> = Vec::new();
        let mut record = |id: u32, what: ObjectId| {
            let i = id as usize;
            if ids.len() <= i {
                ids.resize(i + 1, None);
            }
            ids[i] = Some(what);
        };

        // Meshes: one scene per mesh, instanced, but for the meshes placed once: merged into
        // one scene of world-space triangles, instanced with the identity, as our tracer
        // merges them (`accel::merge`, the same `f32` vertices), so that both trace the same
        // triangles through the same kind of structure.
        let meshes = &scene.meshes;
        let merged = MergedMeshes::of(meshes);
        let needed = own_tree_needed(meshes, merged.as_ref());
        let mut alpha = AlphaFilter::of(meshes);
        let mut mesh_scenes = Vec::with_capacity(meshes.meshes.len() + 1);
        for (m, mesh) in meshes.meshes.iter().enumerate() {
            let s = SceneHandle::with_quality(&device, quality, options.robust)?;
            if needed[m] && !mesh.triangles.is_empty() {
                let g = triangle_geometry(&device, &mesh.positions, &mesh.triangles)?;
                if let Some(a) = alpha.as_mut().filter(|a| a.masked_meshes.contains(&m)) {
                    a.attach(&g);
                    g.commit();
                }
                s.attach(&g);
            }
            s.commit();
            device.check("building a mesh scene")?;
            mesh_scenes.push(s);
        }
        let face_normals = meshes
            .meshes
            .iter()
            .map(|m| {
                m.triangles
                    .iter()
                    .map(|t| {
                        let [a, b, c] = t.map(|i| m.positions[i as usize]);
                        (b - a).cross(c - a)
                    })
                    .collect()
            })
            .collect();
        let mut instances = Vec::with_capacity(meshes.instances.len());
        let mut merged_top = None;
        if let Some(m) = &merged {
            // (no alpha filter: no merged instance has a mask)
            let s = SceneHandle::with_quality(&device, quality, options.robust)?;
            let g = triangle_geometry(&device, &m.positions, &m.triangles)?;
            s.attach(&g);
            s.commit();
            device.check("building the merged meshes' scene")?;
            let g = instance(&device, &s, &Affine3A::IDENTITY)?;
            merged_top = Some((top.attach(&g), m.origin.clone()));
            mesh_scenes.push(s);
        }
        for (k, inst) in meshes.instances.iter().enumerate() {
            instances.push((inst.mesh, inst.normal_matrix));
            if merged.as_ref().is_some_and(|m| m.merged[k]) {
                continue;
            }
            let g = instance(&device, &mesh_scenes[inst.mesh], &inst.transform)?;
            let id = top.attach(&g);
            record(id, ObjectId::MeshInstance(k));
            if let Some(a) = alpha.as_mut() {
                a.set_instance(id, k as u32);
            }
        }

        // The clip box of planes.
        let mut world = scene.finite_bounds().union(&meshes.bounds());
        let cam = scene.camera.position;
        world = world.union(&Aabb::new(cam, cam));
        // The finite extent of partly unbounded objects (a slab, a row of columns): their
        // infinite axes take the extent found so far.
        let found = world;
        for object in &scene.objects {
            let b = object.bounds();
            if !b.is_finite() && !b.is_empty() {
                let lo = Vec3::select(b.min.is_finite_mask(), b.min, found.min);
                let hi = Vec3::select(b.max.is_finite_mask(), b.max, found.max);
                world = world.union(&Aabb::new(lo, hi));
            }
        }
        let clip = world.expand(2.0 * scene.tracer.max_distance);
        let mesh_clip = options
            .mesh_clip
            .unwrap_or_else(|| world.expand((0.1 * world.diagonal()).max(1.0)));
        let mesh_options = MeshOptions {
            resolution: options.mesh_resolution,
            refine: true,
            max_triangles: options.mesh_max_triangles,
        };

        // SDF objects.
        let mut shapes = Vec::new();
        let mut certified = Vec::new();
        let mut checks = Vec::with_capacity(scene.objects.len());
        let mut sdf_face_normals = vec![Vec::new(); scene.objects.len()];
        let mut mesh_regions = vec![None; scene.objects.len()];
        // Mesh every object without a closed form, in parallel over objects as well as over
        // each object's octree leaves (the descent and the welding of one object are serial).
        let mut meshes: Vec<Option<Result<SdfMesh, String>>> = scene
            .objects
            .par_iter()
            .map(|object| {
                (options.meshed && analytic_form(&object.node).is_err()).then(|| {
                    mesher::mesh_sdf(
                        &object.lowered.distance,
                        &object.bounds(),
                        &mesh_clip,
                        &mesh_options,
                    )
                })
            })
            .collect();
        for (i, object) in scene.objects.iter().enumerate() {
            let (m, primitive) = match analytic_form(&object.node) {
                Ok(x) => x,
                Err(_) if !options.meshed => {
                    let bounds = object.bounds();
                    // An unbounded object is searched inside the planes' clip box: every
                    // ray the tracer casts ends inside it.
                    let b = if bounds.is_finite() {
                        bounds
                    } else {
                        bounds.intersection(&clip)
                    };
                    let mut search = options
                        .search
                        .unwrap_or_else(|| certified_search(&scene.tracer));
                    if object.node.guaranteed_lipschitz().is_none() {
                        search.lipschitz = None;
                    }
                    checks.push(SdfCheck::Certified {
                        delta: search.delta,
                        max_boxes: search.max_boxes,
                        lipschitz: search.lipschitz,
                    });
                    if b.is_empty() || !b.is_finite() {
                        // no surface inside the box any ray can reach
                        continue;
                    }
                    // Pad for rounding of the f32 bounds, as for the closed forms.
                    let b = b.expand(1e-4 * b.diagonal() + 1e-6);
                    let shape = Box::new(CertifiedShape {
                        program: Program::new(&object.lowered.distance),
                        tape: object.lowered.distance.interpreted(),
                        search,
                        lo: b.min.as_dvec3(),
                        hi: b.max.as_dvec3(),
                        bounds: rtc_bounds(b.min, b.max),
                        uncertified: AtomicU64::new(0),
                    });
                    let g = user_geometry(&device, &*shape)?;
                    record(top.attach(&g), ObjectId::Sdf(i));
                    certified.push(shape);
                    continue;
                }
                Err(_) => {
                    let meshed = meshes[i]
                        .take()
                        .expect("every object without a closed form was meshed");
                    let mesh = match meshed {
                        Ok(mesh) => mesh,
                        Err(why) => {
                            checks.push(SdfCheck::Skipped {
                                why: format!(
                                    "object {i} ({}) cannot be meshed: {why}",
                                    object.label()
                                ),
                            });
                            continue;
                        }
                    };
                    if !mesh.triangles.is_empty() {
                        // Its own scene of MEDIUM build quality, instanced with the identity:
                        // the top-level scene's HIGH quality (spatial splits) would cost
                        // seconds on millions of small, well-shaped triangles for little gain.
                        let s = SceneHandle::with_quality(
                            &device,
                            RTCBuildQuality::MEDIUM,
                            options.robust,
                        )?;
                        let g = triangle_geometry(&device, &mesh.positions, &mesh.triangles)?;
                        s.attach(&g);
                        s.commit();
                        device.check("building a meshed SDF object's scene")?;
                        let inst = instance(&device, &s, &Affine3A::IDENTITY)?;
                        record(top.attach(&inst), ObjectId::Sdf(i));
                        mesh_scenes.push(s);
                    }
                    sdf_face_normals[i] = face_normals_of(&mesh);
                    mesh_regions[i] = Some(MeshRegion {
                        bounds: mesh.region,
                        clipped: mesh.clipped,
                    });
                    checks.push(SdfCheck::Meshed {
                        resolution: mesh.resolution,
                        cell: mesh.cell,
                        tolerance: mesh.tolerance,
                        triangles: mesh.triangles.len(),
                        clipped_to: mesh
                            .clipped
                            .then(|| [mesh.region.min.to_array(), mesh.region.max.to_array()]),
                    });
                    continue;
                }
            };
            let to_world = daffine(&m);
            let to_object = to_world.inverse();
            let (bounds, clips) = match primitive.bounds() {
                Some((lo, hi)) => {
                    let b = Aabb::new(lo.as_vec3(), hi.as_vec3()).transformed(&m);
                    // Pad for rounding of the f32 bounds.
                    let pad = 1e-4 * b.diagonal() + 1e-6;
                    let b = b.expand(pad);
                    (rtc_bounds(b.min, b.max), false)
                }
                None => (rtc_bounds(clip.min, clip.max), true),
            };
            let shape = Box::new(UserShape {
                primitive,
                to_object,
                normal_to_world: to_object.matrix3.transpose(),
                bounds,
                clip: clips,
            });
            let g = user_geometry(&device, &*shape)?;
            record(top.attach(&g), ObjectId::Sdf(i));
            shapes.push(shape);
            checks.push(SdfCheck::Analytic);
        }
        top.commit();
        device.check("building the scene")?;
        Ok(EmbreeScene {
            top,
            _mesh_scenes: mesh_scenes,
            _shapes: shapes,
            certified,
            _alpha: alpha,
            device,
            ids,
            merged: merged_top,
            face_normals,
            instances,
            sdf_face_normals,
            mesh_regions,
            checks,
        })
    }

    /// What a hit record says, as a [`QueryHit`]: `ids` are its geomID, primID and instID[0],
    /// `ng` its geometric normal (the user geometries' normal; a triangle's is looked up).
    fn query_hit(&self, t: f32, ids: [u32; 3], ng: Vec3) -> Option<QueryHit> {
        let [geom_id, prim_id, inst_id] = ids;
        if geom_id == RTC_INVALID_GEOMETRY_ID {
            return None;
        }
        let (top_id, inside_instance) = if inst_id != RTC_INVALID_GEOMETRY_ID {
            (inst_id, true)
        } else {
            (geom_id, false)
        };
        if let Some((merged_top, origin)) = &self.merged
            && inside_instance
            && top_id == *merged_top
        {
            let &(k, triangle) = origin.get(prim_id as usize)?;
            let (mesh, nm) = self.instances[k as usize];
            let normal = (nm * self.face_normals[mesh][triangle as usize]).normalize_or_zero();
            return Some(QueryHit {
                t,
                normal,
                object: ObjectId::MeshInstance(k as usize),
            });
        }
        let object = self.ids.get(top_id as usize).copied().flatten()?;
        let normal = match object {
            ObjectId::MeshInstance(k) if inside_instance => {
                let (mesh, nm) = self.instances[k];
                (nm * self.face_normals[mesh][prim_id as usize]).normalize_or_zero()
            }
            ObjectId::Sdf(i) if !self.sdf_face_normals[i].is_empty() => {
                self.sdf_face_normals[i][prim_id as usize]
            }
            _ => ng.normalize_or_zero(),
        };
        Some(QueryHit { t, normal, object })
    }

    fn rtc_ray(ray: &Ray, tmin: f32, tmax: f32) -> RTCRay {
        RTCRay {
            org_x: ray.origin.x,
            org_y: ray.origin.y,
            org_z: ray.origin.z,
            dir_x: ray.direction.x,
            dir_y: ray.direction.y,
            dir_z: ray.direction.z,
            tnear: tmin.max(0.0),
            tfar: tmax,
            ..Default::default()
        }
    }
}

/// Whether `[tmin, tmax]` (tmin clamped at 0) holds anything to find: the interval every
/// query, single ray or packet lane, traces.
fn live(tmin: f32, tmax: f32) -> bool {
    !(tmax.is_nan() || tmin.max(0.0) > tmax)
}

impl RayQuery for EmbreeScene {
    fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<QueryHit> {
        if !live(tmin, tmax) {
            return None;
        }
        let mut slot = RayHit {
            ray_hit: RTCRayHit {
                ray: Self::rtc_ray(ray, tmin, tmax),
                hit: RTCHit::default(),
            },
            inst_prim_id: [RTC_INVALID_GEOMETRY_ID; 4],
        };
        // SAFETY: the scene is committed; null arguments mean the defaults; `slot` has room
        // for the larger hit record of a 4.3+ library (see `RayHit`).
        unsafe { embree4_sys::rtcIntersect1(self.top.0, &mut slot.ray_hit, ptr::null_mut()) };
        debug_assert!(self.device.check("rtcIntersect1").is_ok());
        let rh = slot.ray_hit;
        let hit = rh.hit;
        self.query_hit(
            rh.ray.tfar,
            [hit.geomID, hit.primID, hit.instID[0]],
            Vec3::new(hit.Ng_x, hit.Ng_y, hit.Ng_z),
        )
    }

    fn occluded(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        if !live(tmin, tmax) {
            return false;
        }
        let mut r = Self::rtc_ray(ray, tmin, tmax);
        // SAFETY: the scene is committed; null arguments mean the defaults.
        unsafe { embree4_sys::rtcOccluded1(self.top.0, &mut r, ptr::null_mut()) };
        r.tfar == f32::NEG_INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The linked library writes `instPrimID` just past a 4.2 `RTCRayHit` on a hit inside an
    /// instance (see [`RayHit`]): the write lands in the tail, and the hit itself is intact.
    /// With a library that has no such field the tail keeps its marker; either way nothing
    /// outside `RayHit` is touched.
    #[test]
    fn a_hit_record_of_a_newer_library_fits_in_ray_hit() {
        let scene = crate::scene::generate::icosphere_scene(1).expect("icosphere scene");
        let embree = EmbreeScene::build(&scene).expect("Embree scene");
        let marker = 0xdead_beef;
        let mut slot = RayHit {
            ray_hit: RTCRayHit {
                ray: EmbreeScene::rtc_ray(
                    &Ray::new(Vec3::new(0.0, 0.0, 5.0), Vec3::NEG_Z),
                    0.0,
                    100.0,
                ),
                hit: RTCHit::default(),
            },
            inst_prim_id: [marker; 4],
        };
        // SAFETY: as in `closest_hit`.
        unsafe { embree4_sys::rtcIntersect1(embree.top.0, &mut slot.ray_hit, ptr::null_mut()) };
        assert_ne!(
            slot.ray_hit.hit.geomID, RTC_INVALID_GEOMETRY_ID,
            "the ray hits the sphere"
        );
        assert_ne!(
            slot.ray_hit.hit.instID[0], RTC_INVALID_GEOMETRY_ID,
            "inside an instance"
        );
        assert!(
            (slot.ray_hit.ray.tfar - 4.0).abs() < 0.1,
            "{}",
            slot.ray_hit.ray.tfar
        );
        // Only the first tail word may change (to the library's instPrimID, 0 for a plain
        // instance); the padding after it stays.
        assert_eq!(slot.inst_prim_id[1..], [marker; 3]);
        eprintln!(
            "library writes instPrimID past a 4.2 RTCRayHit: {}",
            slot.inst_prim_id[0] != marker
        );
    }
}
