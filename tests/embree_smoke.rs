//! Smoke test of the Embree 4 link: a device, one triangle, a hit, a miss and two shadow rays.
//!
//! It proves end to end that `scripts/setup.sh` + `build.rs` give a binary that links and loads
//! `libembree4` (and its TBB), so that CI fails here, plainly, when Embree is not there.
//! Everything goes through raw `embree4_sys` calls. (The `embree4-rs` wrapper was used for
//! `rtcIntersect1` until we found that it hands Embree a 4.2-sized `RTCRayHit`, which the 4.4
//! library overruns by four bytes on every hit: see `RayHit` in `src/reference/embree.rs`.)
#![cfg(feature = "embree")]

use std::ptr;

use embree4_sys::{
    RTCBufferType, RTCDevice, RTCError, RTCFormat, RTCGeometryType, RTCHit, RTCRay, RTCRayHit,
    RTCScene,
};

const VERTICES: [(f32, f32, f32); 3] = [(-1.0, -1.0, 0.0), (1.0, -1.0, 0.0), (0.0, 1.0, 0.0)];
const INDICES: [(u32, u32, u32); 1] = [(0, 1, 2)];

/// A ray from `org` along `dir`, with `tnear` 0 and the given `tfar`.
fn ray(org: [f32; 3], dir: [f32; 3], tfar: f32) -> RTCRay {
    RTCRay {
        org_x: org[0],
        org_y: org[1],
        org_z: org[2],
        dir_x: dir[0],
        dir_y: dir[1],
        dir_z: dir[2],
        tnear: 0.0,
        tfar,
        ..Default::default()
    }
}

#[test]
fn ray_hits_the_triangle_at_t_3() {
    let scene = RawScene::new();
    let hit = scene
        .intersect(ray([0.0, 0.0, -3.0], [0.0, 0.0, 1.0], f32::INFINITY))
        .expect("the ray should hit the triangle");
    assert!((hit.ray.tfar - 3.0).abs() < 1e-5, "t = {}", hit.ray.tfar);
    assert_eq!(hit.hit.geomID, 0);
    assert_eq!(hit.hit.primID, 0);
    // The geometric normal is along the z axis (its sign follows the winding).
    assert!(hit.hit.Ng_x.abs() < 1e-6 && hit.hit.Ng_y.abs() < 1e-6 && hit.hit.Ng_z.abs() > 0.0);
}

#[test]
fn ray_beside_the_triangle_misses() {
    let scene = RawScene::new();
    let beside = scene.intersect(ray([2.0, 2.0, -3.0], [0.0, 0.0, 1.0], f32::INFINITY));
    assert!(
        beside.is_none(),
        "unexpected hit: geomID {:?}",
        beside.map(|h| h.hit.geomID)
    );
    let away = scene.intersect(ray([0.0, 0.0, -3.0], [0.0, 0.0, -1.0], f32::INFINITY));
    assert!(away.is_none(), "a ray pointing away should miss");
}

/// An `RTCRayHit` with room behind it for the `instPrimID` field that Embree 4.3+ libraries
/// built with instance arrays add to `RTCHit` (the 4.2 bindings do not have it).
#[repr(C, align(16))]
struct PaddedRayHit {
    ray_hit: RTCRayHit,
    _tail: [u32; 4],
}

/// A device and a committed one-triangle scene made with raw `embree4_sys` calls.
struct RawScene {
    device: RTCDevice,
    scene: RTCScene,
}

impl RawScene {
    fn new() -> Self {
        // SAFETY: plain Embree API calls in the documented order; every buffer written here is
        // the one Embree just returned, with the size asked for.
        unsafe {
            let device = embree4_sys::rtcNewDevice(c"verbose=0".as_ptr());
            assert!(!device.is_null(), "rtcNewDevice failed");
            let geometry = embree4_sys::rtcNewGeometry(device, RTCGeometryType::TRIANGLE);
            let vertices = embree4_sys::rtcSetNewGeometryBuffer(
                geometry,
                RTCBufferType::VERTEX,
                0,
                RTCFormat::FLOAT3,
                3 * size_of::<f32>(),
                VERTICES.len(),
            ) as *mut f32;
            assert!(!vertices.is_null());
            for (i, v) in VERTICES.iter().enumerate() {
                *vertices.add(3 * i) = v.0;
                *vertices.add(3 * i + 1) = v.1;
                *vertices.add(3 * i + 2) = v.2;
            }
            let indices = embree4_sys::rtcSetNewGeometryBuffer(
                geometry,
                RTCBufferType::INDEX,
                0,
                RTCFormat::UINT3,
                3 * size_of::<u32>(),
                INDICES.len(),
            ) as *mut u32;
            assert!(!indices.is_null());
            *indices = INDICES[0].0;
            *indices.add(1) = INDICES[0].1;
            *indices.add(2) = INDICES[0].2;
            embree4_sys::rtcCommitGeometry(geometry);

            let scene = embree4_sys::rtcNewScene(device);
            assert_eq!(embree4_sys::rtcAttachGeometry(scene, geometry), 0);
            embree4_sys::rtcReleaseGeometry(geometry);
            embree4_sys::rtcCommitScene(scene);
            assert_eq!(embree4_sys::rtcGetDeviceError(device), RTCError::NONE);
            Self { device, scene }
        }
    }

    /// The closest hit on the ray between `tnear` and `tfar`.
    fn intersect(&self, ray: RTCRay) -> Option<RTCRayHit> {
        let mut slot = PaddedRayHit {
            ray_hit: RTCRayHit {
                ray,
                hit: RTCHit::default(),
            },
            _tail: [0; 4],
        };
        // SAFETY: the scene is committed; a null argument pointer means default arguments;
        // `slot` has room for a 4.3+ library's larger hit record.
        unsafe { embree4_sys::rtcIntersect1(self.scene, &mut slot.ray_hit, ptr::null_mut()) };
        // SAFETY: the device is alive.
        let error = unsafe { embree4_sys::rtcGetDeviceError(self.device) };
        assert_eq!(error, RTCError::NONE);
        (slot.ray_hit.hit.geomID != embree4_sys::RTC_INVALID_GEOMETRY_ID).then_some(slot.ray_hit)
    }

    /// Whether anything lies on the ray between `tnear` and `tfar`.
    fn occluded(&self, mut ray: RTCRay) -> bool {
        // SAFETY: the scene is committed; a null argument pointer means default arguments.
        unsafe { embree4_sys::rtcOccluded1(self.scene, &mut ray, ptr::null_mut()) };
        // SAFETY: the device is alive.
        let error = unsafe { embree4_sys::rtcGetDeviceError(self.device) };
        assert_eq!(error, RTCError::NONE);
        // Embree marks an occluded ray by setting tfar to -inf.
        ray.tfar == f32::NEG_INFINITY
    }
}

impl Drop for RawScene {
    fn drop(&mut self) {
        // SAFETY: both handles came from Embree and are released once.
        unsafe {
            embree4_sys::rtcReleaseScene(self.scene);
            embree4_sys::rtcReleaseDevice(self.device);
        }
    }
}

#[test]
fn shadow_ray_is_occluded_only_when_it_reaches_the_triangle() {
    let scene = RawScene::new();
    let up = [0.0, 0.0, 1.0];
    assert!(
        scene.occluded(ray([0.0, 0.0, -3.0], up, 10.0)),
        "tfar 10 reaches the triangle at t = 3"
    );
    assert!(
        !scene.occluded(ray([0.0, 0.0, -3.0], up, 2.5)),
        "tfar 2.5 stops short of t = 3"
    );
    assert!(
        !scene.occluded(ray([2.0, 2.0, -3.0], up, 10.0)),
        "this ray passes beside it"
    );
}
