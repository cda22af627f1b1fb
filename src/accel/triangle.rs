//! Watertight ray–triangle intersection (Woop, Benthin & Wald, JCGT 2013).
//!
//! Sven Woop, Carsten Benthin, Ingo Wald, "Watertight Ray/Triangle Intersection", *Journal of
//! Computer Graphics Techniques* 2(1), 65–82, 2013 (<http://jcgt.org/published/0002/01/05/>).
//!
//! The ray is turned into the +z axis of a sheared frame: the axis where |d| is largest becomes
//! z (`kz`), the other two are `kx`, `ky` (swapped when d\[kz\] < 0 so the winding is kept),
//! and the shear constants are Sx = d\[kx\]/d\[kz\], Sy = d\[ky\]/d\[kz\], Sz = 1/d\[kz\]
//! (paper, section 3 and listing 1). Every vertex is translated to the ray origin and
//! sheared *by the same floating-point operations whichever triangle it belongs to*, and the
//! 2D edge functions U, V, W of an edge shared by two triangles are computed from the same two
//! products, so they are exact negatives of each other: a ray can never slip between two
//! triangles that share an edge or a vertex. When an edge function is exactly 0 in `f32`, it is
//! recomputed in `f64`, where the products of `f32` values are exact (paper, section 4).
//!
//! Deviations from the listing, all deliberate:
//! - the `f64` fallback recomputes *each* zero edge function on its own (the paper recomputes
//!   all three when one is 0): this way the value of an edge function depends only on the edge
//!   and the ray, never on which triangle asks, which keeps neighbours consistent even when one
//!   of them needs the fallback for a different edge;
//! - no backface culling (the `#ifndef BACKFACE_CULLING` branch of the paper);
//! - the hit distance is t = T/det, compared with `[tmin, tmax]` (closed interval) after the
//!   division rather than before it, so the t that is reported is the t that was tested;
//! - triangles of exactly zero area are rejected by [`is_degenerate`] before reporting a hit
//!   (the paper only rejects det = 0, which the sheared, rounded vertices of a zero-area
//!   triangle do not always produce).

use glam::{DVec3, Vec3, Vec3A};

/// A hit reported by the watertight test: the hit point is `(1 − u − v)·a + u·b + v·c`, at ray
/// parameter `t` (in units of the ray direction, which need not be unit length).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriHit {
    /// Ray parameter of the hit: the hit point is `origin + t·direction`.
    pub t: f32,
    /// Barycentric weight of vertex `b`.
    pub u: f32,
    /// Barycentric weight of vertex `c`.
    pub v: f32,
}

/// Per-ray constants of the watertight test (paper, listing 1, "precalculations").
///
/// Build it once per ray with [`WatertightRay::new`] and reuse it for every triangle. The
/// fields are public for inspection; changing them by hand breaks the test.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WatertightRay {
    /// Ray origin.
    pub origin: Vec3,
    /// Ray direction (any non-zero length: reported t is in units of it).
    pub direction: Vec3,
    /// The axis along which |direction| is largest (ties go to the lower axis).
    pub kz: usize,
    /// First axis of the sheared 2D frame: `(kz + 1) % 3`, swapped with `ky` if d\[kz\] < 0.
    pub kx: usize,
    /// Second axis of the sheared 2D frame: `(kx + 1) % 3` before the swap.
    pub ky: usize,
    /// Shear constant d\[kx\] / d\[kz\].
    pub sx: f32,
    /// Shear constant d\[ky\] / d\[kz\].
    pub sy: f32,
    /// Scale 1 / d\[kz\].
    pub sz: f32,
}

impl WatertightRay {
    /// Precomputes the shear for a ray. The direction must be finite and non-zero for hits to
    /// be reported (a zero or NaN direction never hits anything, it does not panic).
    pub fn new(origin: Vec3, direction: Vec3) -> Self {
        let ad = direction.abs();
        // "calculate dimension where the ray direction is maximal"
        let kz = if ad.x >= ad.y && ad.x >= ad.z {
            0
        } else if ad.y >= ad.z {
            1
        } else {
            2
        };
        const NEXT: [usize; 3] = [1, 2, 0];
        let mut kx = NEXT[kz];
        let mut ky = NEXT[kx];
        let d = direction.to_array();
        // "swap kx and ky dimension to preserve winding direction of triangles"
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        // The three quotients in one division (each lane the IEEE quotient, as one by one): a
        // leaf visit's shear is made for every ray and instance, and three divisions in turn
        // were a third of its cost.
        let s = Vec3A::new(d[kx], d[ky], 1.0) / Vec3A::splat(d[kz]);
        WatertightRay {
            origin,
            direction,
            kz,
            kx,
            ky,
            sx: s.x,
            sy: s.y,
            sz: s.z,
        }
    }

    /// Intersects the triangle (a, b, c): see the free function [`intersect`].
    #[inline]
    pub fn intersect(&self, a: Vec3, b: Vec3, c: Vec3, tmin: f32, tmax: f32) -> Option<TriHit> {
        intersect(self, a, b, c, tmin, tmax)
    }

    /// The test without the zero-area check, for callers that removed degenerate triangles
    /// beforehand (the BVHs do so when they are built). For a triangle that is not
    /// [degenerate](is_degenerate) the result is identical to [`intersect`].
    #[inline(always)]
    pub fn intersect_nondegenerate(
        &self,
        a: Vec3,
        b: Vec3,
        c: Vec3,
        tmin: f32,
        tmax: f32,
    ) -> Option<TriHit> {
        let (kx, ky, kz) = (self.kx, self.ky, self.kz);
        // "calculate vertices relative to ray origin"
        let ar = (a - self.origin).to_array();
        let br = (b - self.origin).to_array();
        let cr = (c - self.origin).to_array();
        // "perform shear and scale of vertices" (the z part is delayed until a hit is known)
        let ax = ar[kx] - self.sx * ar[kz];
        let ay = ar[ky] - self.sy * ar[kz];
        let bx = br[kx] - self.sx * br[kz];
        let by = br[ky] - self.sy * br[kz];
        let cx = cr[kx] - self.sx * cr[kz];
        let cy = cr[ky] - self.sy * cr[kz];
        // "calculate scaled barycentric coordinates": U belongs to a, V to b, W to c.
        let mut u = cx * by - cy * bx;
        let mut v = ax * cy - ay * cx;
        let mut w = bx * ay - by * ax;
        // "fallback to test against edges using double precision": a product of two f32 is
        // exact in f64, so the sign of an edge function that rounds to 0 is decided exactly.
        if u == 0.0 {
            u = edge_f64(cx, by, cy, bx);
        }
        if v == 0.0 {
            v = edge_f64(ax, cy, ay, cx);
        }
        if w == 0.0 {
            w = edge_f64(bx, ay, by, ax);
        }
        // Edge tests, both-sided: the ray must be on the same side of all three edges.
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        // "calculate determinant": 0 when the ray lies in the triangle's plane (or the
        // projected triangle has no area); NaN is rejected too.
        let det = u + v + w;
        if det == 0.0 || det.is_nan() {
            return None;
        }
        // "calculate scaled z-coordinates of vertices and use them to calculate the hit
        // distance"
        let az = self.sz * ar[kz];
        let bz = self.sz * br[kz];
        let cz = self.sz * cr[kz];
        let t_scaled = u * az + v * bz + w * cz;
        // "normalize U, V, W, and T"
        let rcp = 1.0 / det;
        let t = t_scaled * rcp;
        // Written so that NaN fails.
        if !(t >= tmin && t <= tmax) {
            return None;
        }
        Some(TriHit {
            t,
            u: v * rcp,
            v: w * rcp,
        })
    }
}

/// `p·q − r·s` evaluated exactly (products of `f32` are exact in `f64`, the difference is
/// correctly rounded, so its sign is the exact sign), then narrowed to `f32` without letting a
/// tiny non-zero value underflow to a 0 that would lose the sign.
#[inline(never)]
#[cold]
fn edge_f64(p: f32, q: f32, r: f32, s: f32) -> f32 {
    let e = p as f64 * q as f64 - r as f64 * s as f64;
    let f = e as f32;
    if f == 0.0 && e != 0.0 {
        // Smallest subnormal with the right sign.
        if e > 0.0 {
            f32::from_bits(1)
        } else {
            -f32::from_bits(1)
        }
    } else {
        f
    }
}

/// Whether (a, b, c) has exactly zero area: the cross product of two edges, evaluated in `f64`,
/// is the zero vector. The edge differences of `f32` coordinates and their products are exact
/// in `f64` whenever the coordinates of the triangle are within a factor 2^28 of each other in
/// magnitude (and then this is an exact test); outside that range it may misjudge triangles
/// whose area is itself at the rounding level. Non-finite triangles are *not* reported as
/// degenerate (see [`is_finite`]).
pub fn is_degenerate(a: Vec3, b: Vec3, c: Vec3) -> bool {
    let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
    let e1 = b - a;
    let e2 = c - a;
    let n = DVec3::new(
        e1.y * e2.z - e1.z * e2.y,
        e1.z * e2.x - e1.x * e2.z,
        e1.x * e2.y - e1.y * e2.x,
    );
    n == DVec3::ZERO
}

/// Whether every coordinate of the triangle is finite (no NaN, no infinity).
pub fn is_finite(a: Vec3, b: Vec3, c: Vec3) -> bool {
    a.is_finite() && b.is_finite() && c.is_finite()
}

/// Watertight ray–triangle test of `ray_pre` against (a, b, c), both-sided.
///
/// Returns the hit if the ray meets the closed triangle at a parameter t with
/// `tmin <= t <= tmax`; points on an edge or a vertex count as inside, so a ray through an edge
/// shared by two triangles hits at least one of them (usually both, at the same t). Rays lying
/// in the triangle's plane, zero-area triangles (see [`is_degenerate`]), and NaN anywhere give
/// `None`. t is the ray parameter (`origin + t·direction`), so it is a distance only for a unit
/// direction.
#[inline]
pub fn intersect(
    ray_pre: &WatertightRay,
    a: Vec3,
    b: Vec3,
    c: Vec3,
    tmin: f32,
    tmax: f32,
) -> Option<TriHit> {
    let hit = ray_pre.intersect_nondegenerate(a, b, c, tmin, tmax)?;
    // Only candidate hits pay for the zero-area check.
    if is_degenerate(a, b, c) {
        return None;
    }
    Some(hit)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(o: Vec3, d: Vec3) -> WatertightRay {
        WatertightRay::new(o, d)
    }

    fn hit(r: &WatertightRay, t: [Vec3; 3]) -> Option<TriHit> {
        r.intersect(t[0], t[1], t[2], 0.0, f32::INFINITY)
    }

    use crate::rng::Rng;

    #[test]
    fn simple_hit_distance_and_barycentrics() {
        let (a, b, c) = (
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        );
        let r = ray(Vec3::new(0.25, 0.5, 3.0), Vec3::new(0.0, 0.0, -1.0));
        let h = hit(&r, [a, b, c]).unwrap();
        assert_eq!(h.t, 3.0);
        assert!(
            (h.u - 0.25).abs() < 1e-7 && (h.v - 0.5).abs() < 1e-7,
            "{h:?}"
        );
        // Both-sided: from below as well.
        let r = ray(Vec3::new(0.25, 0.5, -2.0), Vec3::new(0.0, 0.0, 2.0));
        let h = hit(&r, [a, b, c]).unwrap();
        assert_eq!(h.t, 1.0, "t is in units of the (non-unit) direction");
        // The reported point is (1−u−v)a + ub + vc for oblique rays too; the error grows as
        // the ray grazes the plane, so the tolerance is divided by |cos θ|.
        let mut rng = Rng::new(7);
        for _ in 0..1000 {
            let tri = [
                rng.vec3_in(-1.0, 1.0),
                rng.vec3_in(-1.0, 1.0),
                rng.vec3_in(-1.0, 1.0),
            ];
            let o = rng.vec3_in(-3.0, 3.0);
            let target = (tri[0] + tri[1] + tri[2]) / 3.0;
            let d = target - o;
            let r = ray(o, d);
            let h = hit(&r, tri).unwrap();
            let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
            let cos = n.dot(d.normalize()).abs();
            let tol = 1e-5 / cos;
            let p = (1.0 - h.u - h.v) * tri[0] + h.u * tri[1] + h.v * tri[2];
            assert!((p - target).length() < tol, "{p} {target} {cos}");
            assert!((h.t - 1.0).abs() < tol, "{} {cos}", h.t);
        }
    }

    #[test]
    fn vertices_and_edges_of_adjacent_triangles() {
        // A quad split along its diagonal; rays aimed exactly at the shared vertices and at
        // points of the shared edge, in every axis-aligned and oblique direction.
        let p = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let t1 = [p[0], p[1], p[2]];
        let t2 = [p[0], p[2], p[3]];
        // Exactly through the shared vertices p0, p2 (the corners where the diagonal ends)
        // and through points of the diagonal: both triangles report the hit.
        for target in [
            p[0],
            p[2],
            Vec3::new(0.5, 0.5, 0.0),
            Vec3::new(0.25, 0.25, 0.0),
        ] {
            for d in [Vec3::new(0.0, 0.0, -1.0), Vec3::new(0.0, 0.0, 1.0)] {
                let r = ray(target - 2.0 * d, d);
                let (h1, h2) = (hit(&r, t1).unwrap(), hit(&r, t2).unwrap());
                assert_eq!((h1.t, h2.t), (2.0, 2.0));
            }
        }
        // Oblique rays aimed at points of the diagonal (the aim is rounded, so the ray
        // passes within an ulp on either side): at least one triangle, at the same t.
        let mut rng = Rng::new(3);
        for _ in 0..10_000 {
            let target = Vec3::splat(0.01 + 0.98 * rng.next_f32()).with_z(0.0);
            let o = rng.vec3_in(-2.0, 2.0).with_z(1.0 + rng.next_f32());
            let r = ray(o, target - o);
            let (h1, h2) = (hit(&r, t1), hit(&r, t2));
            assert!(h1.is_some() || h2.is_some(), "leak at {target} from {o}");
            if let (Some(h1), Some(h2)) = (h1, h2) {
                assert!((h1.t - h2.t).abs() < 1e-6);
            }
        }
        // A vertex shared by a fan of six triangles: every one of them reports it.
        let centre = Vec3::new(0.1, 0.2, 0.3);
        let ring: Vec<Vec3> = (0..6)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / 6.0;
                centre + Vec3::new(a.cos(), a.sin(), 0.1 * (3.0 * a).sin())
            })
            .collect();
        let r = ray(
            centre + Vec3::new(0.3, -0.2, 2.0),
            Vec3::new(-0.3, 0.2, -2.0),
        );
        let hits = (0..6)
            .filter(|&i| hit(&r, [centre, ring[i], ring[(i + 1) % 6]]).is_some())
            .count();
        assert!(hits >= 1, "a ray through a fan vertex must hit the fan");
    }

    #[test]
    fn shared_edge_never_leaks() {
        // Random pairs of triangles sharing an edge, rays through random points of the edge
        // (rounded to f32, so they pass within an ulp on either side): one or both hit, never
        // neither, as long as the two triangles are on opposite sides of the ray's plane
        // through the edge (otherwise the ray may legitimately graze a ridge).
        let mut rng = Rng::new(11);
        let (mut both, mut one) = (0, 0);
        for _ in 0..20_000 {
            let e0 = rng.vec3_in(-1.0, 1.0);
            let e1 = rng.vec3_in(-1.0, 1.0);
            let c1 = rng.vec3_in(-1.0, 1.0);
            let c2 = rng.vec3_in(-1.0, 1.0);
            // Away from the end points, where the two triangles alone do not surround the
            // target.
            let s = 0.01 + 0.98 * rng.next_f32();
            let target = e0 + s * (e1 - e0);
            let o = rng.vec3_in(-4.0, 4.0);
            let d = target - o;
            let n1 = (e1 - e0).cross(c1 - e0);
            let n2 = (e0 - e1).cross(c2 - e1);
            // Consistent orientation (edge used in opposite directions): the ray crosses the
            // two-triangle surface iff it sees both faces from the same side.
            let (s1, s2) = (
                n1.dot(d) / (n1.length() * d.length()),
                n2.dot(d) / (n2.length() * d.length()),
            );
            if s1 * s2 <= 0.0 || s1.abs() < 0.05 || s2.abs() < 0.05 {
                continue;
            }
            let r = ray(o, d);
            let h1 = hit(&r, [e0, e1, c1]).is_some();
            let h2 = hit(&r, [e1, e0, c2]).is_some();
            assert!(h1 || h2, "leak through a shared edge: {e0} {e1} {o}");
            if h1 && h2 {
                both += 1;
            } else {
                one += 1;
            }
        }
        assert!(both + one > 5000, "{both} {one}");
    }

    #[test]
    fn parallel_rays_miss() {
        let tri = [Vec3::ZERO, Vec3::X, Vec3::Y];
        // In the plane of the triangle, through its interior and along an edge.
        assert!(hit(&ray(Vec3::new(-1.0, 0.25, 0.0), Vec3::X), tri).is_none());
        assert!(hit(&ray(Vec3::new(-1.0, 0.0, 0.0), Vec3::X), tri).is_none());
        // Parallel above the plane.
        assert!(hit(&ray(Vec3::new(-1.0, 0.25, 1.0), Vec3::X), tri).is_none());
        // Zero and NaN directions never hit and do not panic.
        assert!(hit(&ray(Vec3::new(0.2, 0.2, 1.0), Vec3::ZERO), tri).is_none());
        assert!(hit(&ray(Vec3::new(0.2, 0.2, 1.0), Vec3::NAN), tri).is_none());
    }

    #[test]
    fn degenerate_triangles_are_rejected() {
        let r = ray(Vec3::new(0.5, 0.0, 1.0), Vec3::new(0.0, 0.0, -1.0));
        let p = Vec3::new(0.5, 0.0, 0.0);
        // Collinear (through the ray's hit point), repeated vertex, single point.
        let cases = [
            [Vec3::ZERO, Vec3::X, Vec3::new(0.3, 0.0, 0.0)],
            [Vec3::ZERO, Vec3::X, Vec3::X],
            [p, p, p],
            // Collinear with non-representable ratios: 0.1, 0.2, 0.3 along a diagonal.
            [Vec3::splat(0.1), Vec3::splat(0.2), Vec3::splat(0.3)],
        ];
        for tri in cases {
            assert!(is_degenerate(tri[0], tri[1], tri[2]), "{tri:?}");
            assert!(hit(&r, tri).is_none(), "{tri:?}");
        }
        let r = ray(Vec3::new(0.2, 0.0, 0.0), Vec3::new(1.0, 1.0, 1.0));
        assert!(hit(&r, cases[3]).is_none());
        // A thin but non-degenerate sliver is hit.
        let sliver = [Vec3::ZERO, Vec3::X, Vec3::new(0.5, 1e-6, 0.0)];
        assert!(!is_degenerate(sliver[0], sliver[1], sliver[2]));
        let r = ray(Vec3::new(0.5, 2e-7, 1.0), Vec3::new(0.0, 0.0, -1.0));
        assert!(hit(&r, sliver).is_some());
        // NaN vertices: no hit, no panic.
        let r = ray(Vec3::new(0.2, 0.2, 1.0), Vec3::new(0.0, 0.0, -1.0));
        assert!(hit(&r, [Vec3::ZERO, Vec3::X, Vec3::new(f32::NAN, 1.0, 0.0)]).is_none());
        assert!(!is_finite(
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(f32::NAN, 1.0, 0.0)
        ));
    }

    #[test]
    fn tmin_tmax_boundaries_are_closed() {
        let tri = [
            Vec3::new(-1.0, -1.0, 2.0),
            Vec3::new(1.0, -1.0, 2.0),
            Vec3::new(0.0, 1.0, 2.0),
        ];
        let r = ray(Vec3::ZERO, Vec3::Z);
        let t = r.intersect(tri[0], tri[1], tri[2], 0.0, 10.0).unwrap().t;
        assert_eq!(t, 2.0);
        assert!(r.intersect(tri[0], tri[1], tri[2], 2.0, 2.0).is_some());
        assert!(r.intersect(tri[0], tri[1], tri[2], 0.0, 2.0).is_some());
        assert!(r.intersect(tri[0], tri[1], tri[2], 2.0, 10.0).is_some());
        let below = f32::from_bits(2.0f32.to_bits() - 1);
        let above = f32::from_bits(2.0f32.to_bits() + 1);
        assert!(r.intersect(tri[0], tri[1], tri[2], 0.0, below).is_none());
        assert!(r.intersect(tri[0], tri[1], tri[2], above, 10.0).is_none());
        // Behind the origin: only with a negative tmin.
        let back = ray(Vec3::new(0.0, 0.0, 5.0), Vec3::Z);
        assert!(back.intersect(tri[0], tri[1], tri[2], 0.0, 10.0).is_none());
        assert_eq!(
            back.intersect(tri[0], tri[1], tri[2], -10.0, 10.0)
                .unwrap()
                .t,
            -3.0
        );
        // A very short ray still hits a very close triangle.
        let near = ray(Vec3::new(0.0, 0.0, 2.0 - 3e-5), Vec3::Z);
        let h = near.intersect(tri[0], tri[1], tri[2], 0.0, 5e-5).unwrap();
        assert!((h.t - 3e-5).abs() < 1e-6);
        // Origin exactly on a vertex: t is exactly 0.
        let on = ray(tri[0], Vec3::new(0.1, 0.2, 1.0));
        assert_eq!(
            on.intersect(tri[0], tri[1], tri[2], 0.0, 1.0).unwrap().t,
            0.0
        );
        // NaN bounds reject.
        assert!(
            r.intersect(tri[0], tri[1], tri[2], f32::NAN, 10.0)
                .is_none()
        );
    }

    #[test]
    fn double_precision_fallback_decides_exact_zeroes() {
        // The ray passes exactly through the shared edge x = y of two triangles; in f32 the
        // edge function is exactly 0, so the sign comes from the f64 path and both triangles
        // agree the point is on the edge.
        let a = Vec3::new(0.0, 0.0, 0.0);
        let b = Vec3::new(1.0, 1.0, 0.0);
        let t1 = [a, b, Vec3::new(1.0, 0.0, 0.0)];
        let t2 = [b, a, Vec3::new(0.0, 1.0, 0.0)];
        let r = ray(Vec3::new(0.3, 0.3, 1.0), Vec3::new(0.0, 0.0, -1.0));
        let (h1, h2) = (hit(&r, t1).unwrap(), hit(&r, t2).unwrap());
        assert_eq!(h1.t, h2.t);
        assert_eq!(edge_f64(1e-30, 1e-30, 0.0, 0.0).signum(), 1.0);
        assert!(
            edge_f64(1e-30, 1e-30, 0.0, 0.0) > 0.0,
            "tiny products keep their sign"
        );
        assert!(edge_f64(0.0, 0.0, 1e-30, 1e-30) < 0.0);
    }
}
