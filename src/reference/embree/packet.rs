//! Embree's packet queries (`rtcIntersect8/16`, `rtcOccluded8/16`) over a batch of rays, for
//! the benchmark: a batch is cut into packets of the width asked, in order, and lanes past the
//! end of the batch or with an empty interval are masked off (the valid mask).
//!
//! Embree 4 has no stream queries (`rtcIntersect1M`/`NM`/`NP` were removed in 4.0), so
//! packets are its only batched form.

use super::{EmbreeScene, RTC_INVALID_GEOMETRY_ID, live};
use crate::geom::Ray;
use crate::trace::query::{QueryHit, RayQuery};
use embree4_sys::{RTCDeviceProperty, RTCRay8, RTCRay16, RTCRayHit8, RTCRayHit16};
use glam::Vec3;
use std::ptr;

/// Lanes of an Embree ray packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum PacketWidth {
    /// `rtcIntersect8` / `rtcOccluded8`.
    Eight,
    /// `rtcIntersect16` / `rtcOccluded16`.
    Sixteen,
}

impl PacketWidth {
    /// Rays per packet.
    pub fn lanes(self) -> usize {
        match self {
            PacketWidth::Eight => 8,
            PacketWidth::Sixteen => 16,
        }
    }
}

/// `RTCRayHitN` as the linked 4.4 library lays it out: its `RTCHitN` ends with
/// `instPrimID[1][N]` after `instID`, which the 4.2 bindings lack (the packet form of
/// [`super::RayHit`]'s overrun); the tail gives that write a place of its own.
#[repr(C)]
struct Padded<R, const N: usize> {
    ray_hit: R,
    inst_prim_id: [u32; N],
}

// The tail starts right where the 4.2 record ends, at the packet's alignment.
const _: () = assert!(size_of::<RTCRayHit8>() == 640 && align_of::<RTCRayHit8>() == 32);
const _: () = assert!(size_of::<RTCRayHit16>() == 1280 && align_of::<RTCRayHit16>() == 64);
const _: () = assert!(std::mem::offset_of!(Padded<RTCRayHit8, 8>, inst_prim_id) == 640);
const _: () = assert!(std::mem::offset_of!(Padded<RTCRayHit16, 16>, inst_prim_id) == 1280);

/// A packet's valid mask (−1: trace the lane, 0: leave it), aligned as Embree requires (to the
/// packet's size in bytes).
#[repr(C, align(64))]
struct Valid<const N: usize>([i32; N]);

/// Writes one packet's rays (lane k from `rays[k]`) and valid mask; lanes past the rays stay
/// invalid. `$r` is an `RTCRayN`.
macro_rules! fill_packet {
    ($r:expr, $valid:expr, $rays:expr, $tmin:expr, $tmax:expr) => {{
        for (k, (ray, &tmax)) in $rays.iter().zip($tmax).enumerate() {
            let ok = live($tmin, tmax);
            $valid.0[k] = if ok { -1 } else { 0 };
            $r.org_x[k] = ray.origin.x;
            $r.org_y[k] = ray.origin.y;
            $r.org_z[k] = ray.origin.z;
            $r.dir_x[k] = ray.direction.x;
            $r.dir_y[k] = ray.direction.y;
            $r.dir_z[k] = ray.direction.z;
            $r.tnear[k] = $tmin.max(0.0);
            $r.tfar[k] = if ok { tmax } else { 0.0 };
            $r.time[k] = 0.0;
            $r.mask[k] = u32::MAX;
            $r.id[k] = k as u32;
            $r.flags[k] = 0;
        }
    }};
}

/// The packet queries of one width: `$closest` (through `$intersect`, `rtcIntersect8` or
/// `16`) and `$occluded` (through `$occl`), each answering one packet of at most `$n` rays.
macro_rules! packet_queries {
    ($closest:ident, $occluded:ident, $rayhit:ty, $ray:ty, $n:literal, $intersect:path, $occl:path) => {
        impl EmbreeScene {
            fn $closest(
                &self,
                rays: &[Ray],
                tmin: f32,
                tmax: &[f32],
                out: &mut [Option<QueryHit>],
            ) {
                let mut valid = Valid::<$n>([0; $n]);
                // SAFETY: every field of the record is a plain number or an array of them;
                // all-zero is a valid value.
                let mut slot: Padded<$rayhit, $n> = unsafe { std::mem::zeroed() };
                fill_packet!(slot.ray_hit.ray, valid, rays, tmin, tmax);
                slot.ray_hit.hit.geomID = [RTC_INVALID_GEOMETRY_ID; $n];
                slot.ray_hit.hit.instID = [[RTC_INVALID_GEOMETRY_ID; $n]];
                slot.inst_prim_id = [RTC_INVALID_GEOMETRY_ID; $n];
                // SAFETY: the scene is committed and has only triangle geometry and instances
                // (the caller checked); the mask and the record are aligned to the packet's
                // size; the record has room for the 4.4 hit (see `Padded`); null arguments
                // mean the defaults.
                unsafe {
                    $intersect(
                        valid.0.as_ptr(),
                        self.top.0,
                        &mut slot.ray_hit,
                        ptr::null_mut(),
                    )
                };
                let (r, h) = (&slot.ray_hit.ray, &slot.ray_hit.hit);
                for (k, out) in out.iter_mut().enumerate() {
                    *out = if valid.0[k] == 0 {
                        None
                    } else {
                        self.query_hit(
                            r.tfar[k],
                            [h.geomID[k], h.primID[k], h.instID[0][k]],
                            Vec3::new(h.Ng_x[k], h.Ng_y[k], h.Ng_z[k]),
                        )
                    };
                }
            }

            fn $occluded(&self, rays: &[Ray], tmin: f32, tmax: &[f32], out: &mut [bool]) {
                let mut valid = Valid::<$n>([0; $n]);
                // SAFETY: as for the closest-hit record.
                let mut r: $ray = unsafe { std::mem::zeroed() };
                fill_packet!(r, valid, rays, tmin, tmax);
                // SAFETY: as for the closest-hit query (an occlusion query writes only `tfar`).
                unsafe { $occl(valid.0.as_ptr(), self.top.0, &mut r, ptr::null_mut()) };
                for (k, out) in out.iter_mut().enumerate() {
                    // Embree's mark for an occluded ray.
                    *out = valid.0[k] != 0 && r.tfar[k] == f32::NEG_INFINITY;
                }
            }
        }
    };
}

packet_queries!(
    closest8,
    occluded8,
    RTCRayHit8,
    RTCRay8,
    8,
    embree4_sys::rtcIntersect8,
    embree4_sys::rtcOccluded8
);
packet_queries!(
    closest16,
    occluded16,
    RTCRayHit16,
    RTCRay16,
    16,
    embree4_sys::rtcIntersect16,
    embree4_sys::rtcOccluded16
);

/// One packet's query: (scene, rays, tmin, their tmax, answers).
type PacketFn<T> = fn(&EmbreeScene, &[Ray], f32, &[f32], &mut [T]);

impl EmbreeScene {
    /// Whether the library runs packets of `width` natively (rather than as narrower ones):
    /// `RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED` / `..._RAY16_...`.
    pub fn native_packets(&self, width: PacketWidth) -> bool {
        let prop = match width {
            PacketWidth::Eight => RTCDeviceProperty::NATIVE_RAY8_SUPPORTED,
            PacketWidth::Sixteen => RTCDeviceProperty::NATIVE_RAY16_SUPPORTED,
        };
        // SAFETY: the device is alive; a property query has no other effect.
        unsafe { embree4_sys::rtcGetDeviceProperty(self.device.0, prop) != 0 }
    }

    /// Whether [`Self::closest_hits`] and [`Self::occluded_many`] really trace packets: our
    /// user geometries' callbacks take one ray at a time, so a scene with SDF objects is
    /// answered ray by ray.
    pub fn traces_packets(&self) -> bool {
        self._shapes.is_empty() && self.certified.is_empty()
    }

    /// The closest hit of every ray over `[tmin, tmax[i]]`, in packets of `width`: the
    /// answers of [`RayQuery::closest_hit`] up to Embree's own packet arithmetic.
    ///
    /// # Panics
    /// When `rays`, `tmax` and `out` differ in length.
    pub fn closest_hits(
        &self,
        width: PacketWidth,
        rays: &[Ray],
        tmin: f32,
        tmax: &[f32],
        out: &mut [Option<QueryHit>],
    ) {
        let packet: PacketFn<_> = match width {
            PacketWidth::Eight => Self::closest8,
            PacketWidth::Sixteen => Self::closest16,
        };
        self.in_packets(width, rays, tmin, tmax, out, Self::closest_hit, packet);
    }

    /// Whether anything blocks each ray over `[tmin, tmax[i]]`, in packets of `width` (see
    /// [`Self::closest_hits`]).
    ///
    /// # Panics
    /// When `rays`, `tmax` and `out` differ in length.
    pub fn occluded_many(
        &self,
        width: PacketWidth,
        rays: &[Ray],
        tmin: f32,
        tmax: &[f32],
        out: &mut [bool],
    ) {
        let packet: PacketFn<_> = match width {
            PacketWidth::Eight => Self::occluded8,
            PacketWidth::Sixteen => Self::occluded16,
        };
        self.in_packets(width, rays, tmin, tmax, out, Self::occluded, packet);
    }

    /// Answers the rays in packets of `width` with `packet`, or one at a time with `one`
    /// when the scene has user geometries (see [`Self::traces_packets`]).
    #[allow(clippy::too_many_arguments)]
    fn in_packets<T>(
        &self,
        width: PacketWidth,
        rays: &[Ray],
        tmin: f32,
        tmax: &[f32],
        out: &mut [T],
        one: fn(&Self, &Ray, f32, f32) -> T,
        packet: PacketFn<T>,
    ) {
        assert!(rays.len() == tmax.len() && rays.len() == out.len());
        if !self.traces_packets() {
            for ((ray, &tmax), out) in rays.iter().zip(tmax).zip(out) {
                *out = one(self, ray, tmin, tmax);
            }
            return;
        }
        let n = width.lanes();
        for ((rays, tmax), out) in rays.chunks(n).zip(tmax.chunks(n)).zip(out.chunks_mut(n)) {
            packet(self, rays, tmin, tmax, out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::generate::icosphere_scene;

    /// Packets of both widths give the single-ray answers, bit for bit in t, in both modes,
    /// on rays that hit, miss, and have empty or NaN intervals, in batches that do not fill
    /// the last packet.
    #[test]
    fn packets_give_the_single_ray_answers() {
        let scene = icosphere_scene(3).expect("icosphere scene");
        let mut rng = crate::rng::Rng::new(7);
        let rays: Vec<Ray> = (0..203)
            .map(|_| {
                let o = Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, 3.0);
                let d = Vec3::new(
                    0.4 * (rng.next_f32() - 0.5),
                    0.4 * (rng.next_f32() - 0.5),
                    -1.0,
                );
                Ray::new(o, d.normalize())
            })
            .collect();
        let tmax: Vec<f32> = (0..rays.len())
            .map(|i| match i % 17 {
                3 => f32::NAN,
                5 => -1.0,
                7 => 2.5,
                _ => 100.0,
            })
            .collect();
        for robust in [true, false] {
            let options = super::super::ReferenceOptions {
                robust,
                ..Default::default()
            };
            let e = EmbreeScene::build_with(&scene, &options).expect("Embree scene");
            assert!(e.traces_packets());
            for width in [PacketWidth::Eight, PacketWidth::Sixteen] {
                let mut hits = vec![None; rays.len()];
                e.closest_hits(width, &rays, 0.0, &tmax, &mut hits);
                let mut blocked = vec![false; rays.len()];
                e.occluded_many(width, &rays, 0.0, &tmax, &mut blocked);
                let mut some = 0;
                for (i, ray) in rays.iter().enumerate() {
                    let one = e.closest_hit(ray, 0.0, tmax[i]);
                    assert_eq!(
                        hits[i].map(|h| (h.t.to_bits(), h.object)),
                        one.map(|h| (h.t.to_bits(), h.object)),
                        "ray {i}, {width:?}, robust {robust}"
                    );
                    assert_eq!(blocked[i], e.occluded(ray, 0.0, tmax[i]), "ray {i}");
                    some += usize::from(one.is_some());
                }
                assert!(some > 50 && some < 190, "{some} hits");
            }
        }
    }
}
