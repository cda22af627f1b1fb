//! Smoke test of the Embree 4 link: a device, one triangle, a hit, a miss and two shadow rays.
//!
//! It proves end to end that `scripts/setup.sh` + `build.rs` give a binary that links and loads
//! `libembree4` (and its TBB), so that CI fails here, plainly, when Embree is not there.
//! Intersection goes through `embree4-rs`; occlusion goes through `embree4_sys::rtcOccluded1`,
//! which `embree4-rs` does not wrap. `embree4-rs` keeps its device and scene handles private, so
//! the occlusion test builds its scene with raw `embree4_sys` calls.
#![cfg(feature = "embree")]

use std::ptr;

use embree4_rs::geometry::TriangleMeshGeometry;
use embree4_rs::{CommittedScene, Device, Scene, SceneOptions};
use embree4_sys::{
    RTCBufferType, RTCDevice, RTCError, RTCFormat, RTCGeometryType, RTCRay, RTCScene,
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

fn triangle_scene() -> CommittedScene {
    // embree4-rs passes the config string to rtcNewDevice as is, without adding a NUL.
    let device = Device::try_new(Some("verbose=0\0")).expect("rtcNewDevice failed");
    let scene = Scene::try_new(device, SceneOptions::default()).expect("rtcNewScene failed");
    let mesh = TriangleMeshGeometry::try_new(&scene.device, &VERTICES, &INDICES)
        .expect("triangle geometry");
    let geom_id = scene.attach_geometry(&mesh).expect("rtcAttachGeometry");
    assert_eq!(geom_id, 0);
    // The scene holds its own reference to the geometry, so `mesh` may go before the commit.
    drop(mesh);
    scene.commit().expect("rtcCommitScene")
}

#[test]
fn ray_hits_the_triangle_at_t_3() {
    let scene = triangle_scene();
    let hit = scene
        .intersect_1(ray([0.0, 0.0, -3.0], [0.0, 0.0, 1.0], f32::INFINITY), None)
        .expect("rtcIntersect1")
        .expect("the ray should hit the triangle");
    assert!((hit.ray.tfar - 3.0).abs() < 1e-5, "t = {}", hit.ray.tfar);
    assert_eq!(hit.hit.geomID, 0);
    assert_eq!(hit.hit.primID, 0);
    // The geometric normal is along the z axis (its sign follows the winding).
    assert!(hit.hit.Ng_x.abs() < 1e-6 && hit.hit.Ng_y.abs() < 1e-6 && hit.hit.Ng_z.abs() > 0.0);
}

#[test]
fn ray_beside_the_triangle_misses() {
    let scene = triangle_scene();
    let beside = scene
        .intersect_1(ray([2.0, 2.0, -3.0], [0.0, 0.0, 1.0], f32::INFINITY), None)
        .expect("rtcIntersect1");
    assert!(
        beside.is_none(),
        "unexpected hit: geomID {:?}",
        beside.map(|h| h.hit.geomID)
    );
    let away = scene
        .intersect_1(ray([0.0, 0.0, -3.0], [0.0, 0.0, -1.0], f32::INFINITY), None)
        .expect("rtcIntersect1");
    assert!(away.is_none(), "a ray pointing away should miss");
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
