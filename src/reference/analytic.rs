//! Closed-form ray intersections with the SDF primitives, in f64: the analytic ground truth.
//!
//! Every function takes a ray `ro + t * rd` in the primitive's object space and returns the
//! nearest surface crossing with `tmin < t < tmax` (both bounds exclusive), or `None`.
//! Conventions shared by all of them:
//!
//! * `rd` need not be unit length; `t` is always in units of `rd` as given, so the hit point is
//!   exactly `ro + t * rd` (the torus normalises `rd` internally and converts back).
//! * The solids are closed sets. A ray that starts inside (or whose `tmin` lies inside) reports
//!   the exit point. A ray that lies exactly in a face plane of a box/cap counts as touching it.
//! * `normal` is the unit *outward* normal of the solid at the hit, for exits as well as entries
//!   (so for an exit it points along the ray). On an edge or rim it is the normal of one of the
//!   faces that meet there; either is a valid outward normal of the convex solid.
//! * Exactly tangent rays may or may not report the touch point; a ray that passes through the
//!   solid by more than rounding error is always reported.
//! * Degenerate input (non-finite `ro`/`rd`, `rd == 0`, sizes that are not positive) gives `None`.
//!
//! Methods. The convex primitives (box, cylinder, cone, capsule, sphere, ellipsoid) clip the
//! ray's line against each bounding surface in turn: the slab method of Kay & Kajiya (1986),
//! generalised to quadric sides as in Quilez's intersector articles
//! (<https://iquilezles.org/articles/intersectors/>). That yields the chord `[enter, exit]` in
//! one pass, handles rays starting inside for free, and leaves no cracks along edges and rims
//! (testing each face's hit against the other faces' extents, with tolerances, can). Quadratics
//! take the cancellation-free root pair `q / a`, `c / q` (Numerical Recipes §5.6), with the
//! discriminant rewritten by Lagrange's identity as `a r^2 - |o x d|^2` (Haines et al.,
//! "Precision Improvements for Ray/Sphere Intersection", Ray Tracing Gems ch. 7, 2019). The
//! torus quartic is solved by isolating its real roots between the roots of its derivatives and
//! polishing each with bracketed Newton in f64, rather than by the closed-form resolvent-cubic
//! (Ferrari) solution, whose ill-conditioning can lose or misplace the close root pairs of
//! grazing rays.
//!
//! This is the ground truth the sphere tracer (Hart, "Sphere tracing", The Visual Computer,
//! 1996) is tested against; the same functions are meant to serve as Embree user-geometry
//! intersection callbacks, so they allocate nothing and never panic.

use glam::DVec3;

/// A ray–surface intersection found by one of the closed-form intersectors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AnalyticHit {
    /// Ray parameter of the hit, in units of the `rd` passed in: the hit point is `ro + t * rd`.
    pub t: f64,
    /// Unit outward normal of the solid at the hit point (also when the ray is exiting).
    pub normal: DVec3,
}

/// Nearest intersection with the sphere `|p| = radius` centred at the origin.
///
/// Requires `radius > 0`. Rays starting inside report the exit.
pub fn sphere(ro: DVec3, rd: DVec3, radius: f64, tmin: f64, tmax: f64) -> Option<AnalyticHit> {
    if !(ray_ok(ro, rd) && radius > 0.0) {
        return None;
    }
    let (t0, t1) = sphere_chord(ro, rd, radius)?;
    let (t, ()) = Span::chord(t0, t1, ()).first_crossing(tmin, tmax)?;
    let p = ro + t * rd;
    Some(AnalyticHit {
        t,
        normal: unit_or(p, DVec3::Y),
    })
}

/// Nearest intersection with the axis-aligned box `|p.x| <= h.x, |p.y| <= h.y, |p.z| <= h.z`
/// centred at the origin, `h = half_extents` (all components positive).
///
/// Slab method (Kay & Kajiya 1986): the chord is the intersection of the three slab intervals.
/// A ray parallel to a slab is either entirely inside it (no constraint) or misses the box; a
/// ray lying exactly in a face plane counts as inside that slab. The normal is the face normal
/// of the slab that bounds the reported end of the chord.
pub fn box_(
    ro: DVec3,
    rd: DVec3,
    half_extents: DVec3,
    tmin: f64,
    tmax: f64,
) -> Option<AnalyticHit> {
    if !ray_ok(ro, rd) || !half_extents.cmpgt(DVec3::ZERO).all() || !half_extents.is_finite() {
        return None;
    }
    let mut span = Span::line(DVec3::ZERO);
    for (i, axis) in DVec3::AXES.into_iter().enumerate() {
        let h = half_extents[i];
        if !span.slab(ro[i], rd[i], -h, h, -axis, axis) {
            return None;
        }
    }
    let (t, normal) = span.first_crossing(tmin, tmax)?;
    Some(AnalyticHit { t, normal })
}

/// Intersection with the plane `normal · p = offset`; the solid is the half-space
/// `normal · p <= offset`, so the returned normal is always `normal` (normalised).
///
/// A ray parallel to the plane (`normal · rd == 0`) never hits it, even when lying in it.
pub fn plane(
    ro: DVec3,
    rd: DVec3,
    normal: DVec3,
    offset: f64,
    tmin: f64,
    tmax: f64,
) -> Option<AnalyticHit> {
    if !ray_ok(ro, rd) || !normal.is_finite() || !offset.is_finite() {
        return None;
    }
    let n = normal.try_normalize()?;
    // The parameter is invariant under scaling of (normal, offset), so use them unnormalised.
    let denom = normal.dot(rd);
    if denom == 0.0 {
        return None;
    }
    let t = (offset - normal.dot(ro)) / denom;
    (t > tmin && t < tmax).then_some(AnalyticHit { t, normal: n })
}

/// Nearest intersection with the torus lying in the xz-plane around the y axis,
/// `(|p.xz| - major)^2 + p.y^2 = minor^2`, i.e. the zero set of Quilez's `sdTorus`.
///
/// Requires `major > 0` and `minor > 0`. `minor > major` (a self-intersecting "spindle" torus)
/// is supported: the solid is still `sdTorus <= 0`, and roots of the quartic on its inner
/// "lemon" branch, which lie inside that solid, are discarded.
///
/// Squaring out the square root gives the quartic
/// `(|p|^2 + R^2 - r^2)^2 - 4 R^2 (p.x^2 + p.z^2) = 0` in the ray parameter. To keep its
/// coefficients well conditioned, `rd` is normalised and the origin moved to the point of the
/// line closest to the torus centre; roots are only searched inside the (slightly padded)
/// bounding sphere of radius `R + r`. The real roots are isolated between the roots of the
/// quartic's derivatives (on each interval between them it is monotone) and polished by
/// bracketed Newton, so the close root pairs of grazing rays are found, down to depths of about
/// 1e-13 of the torus' size in the tests.
pub fn torus(
    ro: DVec3,
    rd: DVec3,
    major: f64,
    minor: f64,
    tmin: f64,
    tmax: f64,
) -> Option<AnalyticHit> {
    if !(ray_ok(ro, rd) && major > 0.0 && minor > 0.0 && (major + minor).is_finite()) {
        return None;
    }
    let len = rd.length();
    let d = rd / len;
    // Padding keeps roots on the bounding sphere itself (e.g. the outer equator) strictly inside
    // the search interval, where a sign change is reliably seen.
    let bound = (major + minor) * 1.001;
    let sc = -ro.dot(d);
    let p0 = ro + sc * d;
    let h2 = p0.length_squared();
    if h2 >= bound * bound {
        return None;
    }
    let half = (bound * bound - h2).sqrt();
    // Search interval in u = t * |rd| - sc, the distance from p0.
    let lo = (-half).max(tmin * len - sc);
    let hi = half.min(tmax * len - sc);
    // (Neither is NaN: f64::max/min drop a NaN bound, and t > tmin rejects every root then.)
    if lo >= hi {
        return None;
    }

    // p(u) = p0 + u d.  |p|^2 + R^2 - r^2 = dd u^2 + 2 b u + c0, and
    // p.x^2 + p.z^2 = e u^2 + 2 m u + rho2.
    let dd = d.length_squared();
    let b = p0.dot(d);
    let c0 = h2 + (major - minor) * (major + minor);
    let e = d.x * d.x + d.z * d.z;
    let m = p0.x * d.x + p0.z * d.z;
    let rho2 = p0.x * p0.x + p0.z * p0.z;
    let k = 4.0 * major * major;
    let coeffs = [
        c0 * c0 - k * rho2,
        4.0 * b * c0 - 2.0 * k * m,
        4.0 * b * b + 2.0 * dd * c0 - k * e,
        4.0 * b * dd,
        dd * dd,
    ];
    let mut roots = Roots::new();
    poly_roots(&coeffs, lo, hi, 4.0 * f64::EPSILON * bound, &mut roots);

    for &u in roots.as_slice() {
        let t = (sc + u) / len;
        if !(t > tmin && t < tmax) {
            continue;
        }
        let p = p0 + u * d;
        let rho = p.x.hypot(p.z);
        if minor > major {
            // The quartic is the product ((rho - R)^2 + y^2 - r^2) ((rho + R)^2 + y^2 - r^2);
            // only the first factor is the torus surface.
            let on_torus = ((rho - major).hypot(p.y) - minor).abs();
            let on_lemon = ((rho + major).hypot(p.y) - minor).abs();
            if on_lemon < on_torus {
                continue;
            }
        }
        // Outward normal: from the nearest point of the tube's core circle to p.
        let normal = if rho > 0.0 {
            let core = DVec3::new(p.x / rho, 0.0, p.z / rho) * major;
            unit_or(p - core, DVec3::new(0.0, p.y.signum(), 0.0))
        } else {
            // Only reachable at the poles of a spindle torus, where the surface has a conical
            // dimple; the axis direction points out of the solid there.
            DVec3::new(0.0, p.y.signum(), 0.0)
        };
        return Some(AnalyticHit { t, normal });
    }
    None
}

/// Nearest intersection with the capped cylinder around the y axis:
/// `p.x^2 + p.z^2 <= radius^2` and `|p.y| <= half_height`, with flat caps.
///
/// Requires `half_height > 0` and `radius > 0`. The chord is the cap slab intersected with the
/// infinite cylinder's interval; the normal is `±y` on a cap and radial on the side.
pub fn capped_cylinder(
    ro: DVec3,
    rd: DVec3,
    half_height: f64,
    radius: f64,
    tmin: f64,
    tmax: f64,
) -> Option<AnalyticHit> {
    if !(ray_ok(ro, rd) && half_height > 0.0 && radius > 0.0) {
        return None;
    }
    let h = half_height;
    let mut span = Span::line(Face::Curved);
    if !span.slab(
        ro.y,
        rd.y,
        -h,
        h,
        Face::Flat(-DVec3::Y),
        Face::Flat(DVec3::Y),
    ) {
        return None;
    }
    // Side: |o.xz + t d.xz|^2 <= r^2. By Lagrange's identity disc = b^2 - a c equals
    // a r^2 - (o.xz x d.xz)^2, which does not cancel catastrophically for distant origins.
    let a = rd.x * rd.x + rd.z * rd.z;
    let b = ro.x * rd.x + ro.z * rd.z;
    let c = ro.x * ro.x + ro.z * ro.z - radius * radius;
    let cross = ro.x * rd.z - ro.z * rd.x;
    let disc = a * radius * radius - cross * cross;
    match quadratic_nonpositive(a, b, c, disc) {
        Quadratic::Interval(t0, t1) => span.clip(t0, Face::Curved, t1, Face::Curved),
        // With a >= 0 the set is never two rays; anything else means no part of the line is
        // within the side wall.
        _ => return None,
    }
    let (t, face) = span.first_crossing(tmin, tmax)?;
    let normal = match face {
        Face::Flat(n) => n,
        Face::Curved => {
            let p = ro + t * rd;
            unit_or(DVec3::new(p.x, 0.0, p.z), DVec3::X)
        }
    };
    Some(AnalyticHit { t, normal })
}

/// Nearest intersection with the capsule: points within `radius` of the segment `a`–`b`.
///
/// Requires `radius > 0`; `a == b` gives a sphere. The capsule is convex and is the union of two
/// end spheres and a finite cylinder, so the line's chord through it is the hull of the
/// three chords. The normal points from the nearest point of the segment to the hit, which is
/// exact on every part of the surface.
pub fn capsule(
    ro: DVec3,
    rd: DVec3,
    a: DVec3,
    b: DVec3,
    radius: f64,
    tmin: f64,
    tmax: f64,
) -> Option<AnalyticHit> {
    if !(ray_ok(ro, rd) && a.is_finite() && b.is_finite() && radius > 0.0) {
        return None;
    }
    let mut enter = f64::INFINITY;
    let mut exit = f64::NEG_INFINITY;
    let mut include = |t0: f64, t1: f64| {
        enter = enter.min(t0);
        exit = exit.max(t1);
    };
    for end in [a, b] {
        if let Some((t0, t1)) = sphere_chord(ro - end, rd, radius) {
            include(t0, t1);
        }
    }
    let axis = b - a;
    let length = axis.length();
    if length > 0.0 {
        let u = axis / length;
        let w = ro - a;
        let mut span = Span::line(());
        if span.slab(w.dot(u), rd.dot(u), 0.0, length, (), ()) {
            // Side wall: the components of w and rd perpendicular to the axis. Their cross
            // product is parallel to u with length |(w x rd) . u|.
            let wp = w - w.dot(u) * u;
            let dp = rd - rd.dot(u) * u;
            let qa = dp.length_squared();
            let qb = wp.dot(dp);
            let qc = wp.length_squared() - radius * radius;
            let cross = w.cross(rd).dot(u);
            let disc = qa * radius * radius - cross * cross;
            if let Quadratic::Interval(t0, t1) = quadratic_nonpositive(qa, qb, qc, disc) {
                span.clip(t0, (), t1, ());
                if !span.is_empty() {
                    include(span.enter, span.exit);
                }
            }
        }
    }
    let (t, ()) = Span::chord(enter, exit, ()).first_crossing(tmin, tmax)?;
    let p = ro + t * rd;
    let s = if length > 0.0 {
        ((p - a).dot(axis) / axis.length_squared()).clamp(0.0, 1.0)
    } else {
        0.0
    };
    Some(AnalyticHit {
        t,
        normal: unit_or(p - (a + s * axis), DVec3::Y),
    })
}

/// Nearest intersection with the capped cone (frustum) around the y axis: radius `r_bottom` at
/// `y = -half_height`, `r_top` at `y = +half_height`, linear in between, with flat caps.
///
/// Requires `half_height > 0`, both radii `>= 0` and not both zero; a zero radius makes that end
/// a point (apex). Equal radii give a cylinder.
///
/// With `rho(y) = k y + c` the radius at height y, the side is part of the double cone
/// `x^2 + z^2 = rho(y)^2`. Inside the cap slab `rho >= 0`, so the solid is exactly
/// slab ∩ {x^2 + z^2 <= rho(y)^2}. Along a line that quadric set is an interval, two rays (a
/// line crossing both nappes), everything or nothing; its piece inside the slab is the chord
/// (the other nappe lies beyond the apex, outside the slab).
pub fn capped_cone(
    ro: DVec3,
    rd: DVec3,
    half_height: f64,
    r_bottom: f64,
    r_top: f64,
    tmin: f64,
    tmax: f64,
) -> Option<AnalyticHit> {
    let sizes_ok = half_height > 0.0 && r_bottom >= 0.0 && r_top >= 0.0;
    if !(ray_ok(ro, rd) && sizes_ok && r_bottom.max(r_top) > 0.0) {
        return None;
    }
    let h = half_height;
    let mut slab = Span::line(Face::Curved);
    if !slab.slab(
        ro.y,
        rd.y,
        -h,
        h,
        Face::Flat(-DVec3::Y),
        Face::Flat(DVec3::Y),
    ) {
        return None;
    }
    let k = (r_top - r_bottom) / (2.0 * h);
    let c_mid = 0.5 * (r_top + r_bottom);
    // q(t) = |o.xz + t d.xz|^2 - (w + t v)^2 with w = rho(o.y), v = k d.y.
    let w = k * ro.y + c_mid;
    let v = k * rd.y;
    let (o2, d2) = (DVec3::new(ro.x, 0.0, ro.z), DVec3::new(rd.x, 0.0, rd.z));
    let a = d2.length_squared() - v * v;
    let b = o2.dot(d2) - w * v;
    let c = o2.length_squared() - w * w;
    // b^2 - a c expands to |w d.xz - v o.xz|^2 - (o.xz x d.xz)^2.
    let cross = ro.x * rd.z - ro.z * rd.x;
    let disc = (w * d2 - v * o2).length_squared() - cross * cross;

    let span = match quadratic_nonpositive(a, b, c, disc) {
        Quadratic::Empty => return None,
        Quadratic::Interval(t0, t1) => {
            let mut s = slab;
            s.clip(t0, Face::Curved, t1, Face::Curved);
            s
        }
        Quadratic::TwoRays(t0, t1) => {
            let mut below = slab;
            below.clip(f64::NEG_INFINITY, Face::Curved, t0, Face::Curved);
            let mut above = slab;
            above.clip(t1, Face::Curved, f64::INFINITY, Face::Curved);
            // At most one piece is really inside the slab; rounding can leave a zero-length
            // sliver of the other when the line passes through an apex lying on a cap.
            match (below.is_empty(), above.is_empty()) {
                (true, true) => return None,
                (false, true) => below,
                (true, false) => above,
                (false, false) if below.exit - below.enter >= above.exit - above.enter => below,
                (false, false) => above,
            }
        }
    };
    let (t, face) = span.first_crossing(tmin, tmax)?;
    let normal = match face {
        Face::Flat(n) => n,
        Face::Curved => {
            // Gradient of x^2 + z^2 - rho(y)^2 is 2 (x, -k rho, z); on the surface rho = |p.xz|.
            let p = ro + t * rd;
            let rho = p.x.hypot(p.z);
            unit_or(
                DVec3::new(p.x, -k * rho, p.z),
                DVec3::new(0.0, -k.signum(), 0.0),
            )
        }
    };
    Some(AnalyticHit { t, normal })
}

/// Nearest intersection with the axis-aligned ellipsoid `(x/rx)^2 + (y/ry)^2 + (z/rz)^2 = 1`
/// centred at the origin, `radii = (rx, ry, rz)` all positive.
///
/// Scaling space by `1 / radii` maps it to the unit sphere and keeps the ray parameter; the
/// normal is the gradient `p / radii^2`, normalised.
pub fn ellipsoid(ro: DVec3, rd: DVec3, radii: DVec3, tmin: f64, tmax: f64) -> Option<AnalyticHit> {
    if !ray_ok(ro, rd) || !radii.cmpgt(DVec3::ZERO).all() || !radii.is_finite() {
        return None;
    }
    let (t0, t1) = sphere_chord(ro / radii, rd / radii, 1.0)?;
    let (t, ()) = Span::chord(t0, t1, ()).first_crossing(tmin, tmax)?;
    let p = ro + t * rd;
    Some(AnalyticHit {
        t,
        normal: unit_or(p / (radii * radii), DVec3::Y),
    })
}

// ---------------------------------------------------------------------------------------------
// Shared machinery.

fn ray_ok(ro: DVec3, rd: DVec3) -> bool {
    ro.is_finite() && rd.is_finite() && rd != DVec3::ZERO
}

fn unit_or(v: DVec3, fallback: DVec3) -> DVec3 {
    v.try_normalize().unwrap_or(fallback)
}

/// What bounds one end of a chord through a solid with flat and curved faces.
#[derive(Clone, Copy, Debug)]
enum Face {
    /// A plane face with this outward normal.
    Flat(DVec3),
    /// The curved side; the normal is computed from the hit point.
    Curved,
}

/// The chord `[enter, exit]` of a line through a convex solid, with the face bounding each end.
#[derive(Clone, Copy, Debug)]
struct Span<F> {
    enter: f64,
    enter_face: F,
    exit: f64,
    exit_face: F,
}

impl<F: Copy> Span<F> {
    /// The whole line, before any clipping.
    fn line(face: F) -> Self {
        Self::chord(f64::NEG_INFINITY, f64::INFINITY, face)
    }

    fn chord(enter: f64, exit: f64, face: F) -> Self {
        Span {
            enter,
            enter_face: face,
            exit,
            exit_face: face,
        }
    }

    /// Intersects with `[lo, hi]`. On ties the earlier face is kept, which is harmless: at a tie
    /// the point lies on both faces.
    fn clip(&mut self, lo: f64, lo_face: F, hi: f64, hi_face: F) {
        if lo > self.enter {
            self.enter = lo;
            self.enter_face = lo_face;
        }
        if hi < self.exit {
            self.exit = hi;
            self.exit_face = hi_face;
        }
    }

    /// Intersects with the slab `lo <= o + t d <= hi` of one coordinate. Returns false when the
    /// line is parallel to the slab and outside it (the chord is then empty).
    fn slab(&mut self, o: f64, d: f64, lo: f64, hi: f64, lo_face: F, hi_face: F) -> bool {
        if d == 0.0 {
            // Tested explicitly: (lo - o) / 0 would be NaN when o lies on the face.
            return lo <= o && o <= hi;
        }
        let (t_lo, t_hi) = ((lo - o) / d, (hi - o) / d);
        if d > 0.0 {
            self.clip(t_lo, lo_face, t_hi, hi_face);
        } else {
            self.clip(t_hi, hi_face, t_lo, lo_face);
        }
        true
    }

    fn is_empty(&self) -> bool {
        self.enter > self.exit || self.enter.is_nan() || self.exit.is_nan()
    }

    /// The first end of the chord strictly inside `(tmin, tmax)`: the entry, or the exit when the
    /// ray (from `tmin` on) starts inside.
    fn first_crossing(&self, tmin: f64, tmax: f64) -> Option<(f64, F)> {
        if self.is_empty() {
            return None;
        }
        if self.enter > tmin {
            return (self.enter < tmax).then_some((self.enter, self.enter_face));
        }
        (self.exit > tmin && self.exit < tmax).then_some((self.exit, self.exit_face))
    }
}

/// Chord `(t0, t1)` of the line `o + t d` through the ball `|p| <= r`, if it meets it.
fn sphere_chord(o: DVec3, d: DVec3, r: f64) -> Option<(f64, f64)> {
    let a = d.length_squared();
    let b = o.dot(d);
    let c = o.length_squared() - r * r;
    // b^2 - a c = a r^2 - |o x d|^2 (Lagrange's identity), without the catastrophic cancellation
    // of b^2 - a c for distant origins (Ray Tracing Gems ch. 7).
    let disc = a * r * r - o.cross(d).length_squared();
    match quadratic_nonpositive(a, b, c, disc) {
        Quadratic::Interval(t0, t1) => Some((t0, t1)),
        _ => None,
    }
}

/// The set of `t` where `a t^2 + 2 b t + c <= 0`.
#[derive(Clone, Copy, Debug)]
enum Quadratic {
    Empty,
    /// `[t0, t1]`, possibly unbounded on either side.
    Interval(f64, f64),
    /// `(-inf, t0] ∪ [t1, inf)`.
    TwoRays(f64, f64),
}

/// Solves `a t^2 + 2 b t + c <= 0` given the discriminant `disc = b^2 - a c`, which callers
/// compute in a cancellation-free form for their geometry.
fn quadratic_nonpositive(a: f64, b: f64, c: f64, disc: f64) -> Quadratic {
    const INF: f64 = f64::INFINITY;
    if a == 0.0 {
        if b == 0.0 {
            return if c <= 0.0 {
                Quadratic::Interval(-INF, INF)
            } else {
                Quadratic::Empty
            };
        }
        let t = -c / (2.0 * b);
        return if b > 0.0 {
            Quadratic::Interval(-INF, t)
        } else {
            Quadratic::Interval(t, INF)
        };
    }
    if disc < 0.0 || disc.is_nan() {
        return if a > 0.0 {
            Quadratic::Empty
        } else {
            Quadratic::Interval(-INF, INF)
        };
    }
    // Both roots without subtracting nearly equal numbers: q has the magnitude of the larger.
    let q = -(b + disc.sqrt().copysign(b));
    let (r0, r1) = if q == 0.0 {
        // b = 0 and disc = 0, hence c = 0: a double root at 0.
        (0.0, 0.0)
    } else {
        let (x, y) = (q / a, c / q);
        (x.min(y), x.max(y))
    };
    if a > 0.0 {
        Quadratic::Interval(r0, r1)
    } else {
        Quadratic::TwoRays(r0, r1)
    }
}

/// Up to four real roots, strictly ascending.
#[derive(Clone, Copy, Debug)]
struct Roots {
    buf: [f64; 4],
    len: usize,
}

impl Roots {
    fn new() -> Self {
        Roots {
            buf: [0.0; 4],
            len: 0,
        }
    }

    /// Appends `x` unless it repeats (or precedes) the last root.
    fn push(&mut self, x: f64) {
        if self.len < self.buf.len() && (self.len == 0 || x > self.buf[self.len - 1]) {
            self.buf[self.len] = x;
            self.len += 1;
        }
    }

    fn as_slice(&self) -> &[f64] {
        &self.buf[..self.len]
    }
}

/// `(p(x), p'(x), sum |c_i| |x|^i)` by Horner, for `p(x) = sum c_i x^i` (ascending
/// coefficients). The last value scales the rounding error of `p(x)` (Higham, "Accuracy and
/// Stability of Numerical Algorithms", §5.1).
fn horner(c: &[f64], x: f64) -> (f64, f64, f64) {
    let (mut p, mut dp, mut mag) = (0.0, 0.0, 0.0);
    for &ci in c.iter().rev() {
        dp = dp * x + p;
        p = p * x + ci;
        mag = mag * x.abs() + ci.abs();
    }
    (p, dp, mag)
}

/// Appends the real roots in `[lo, hi]` of the polynomial with ascending coefficients `c`
/// (degree at most 4) to `out`, in ascending order.
///
/// Between consecutive critical points (real roots of `p'`, found by recursing on the
/// derivative) `p` is monotone, so each such interval holds a root exactly when `p` changes sign
/// across it, and then only one: it is found by [`refine_root`]. A critical point where `|p|` is
/// within rounding error of zero is reported as a (double) root: that is a ray touching the
/// surface, which plain sign-change bracketing would miss.
fn poly_roots(c: &[f64], lo: f64, hi: f64, xtol: f64, out: &mut Roots) {
    let n = c.len();
    if n < 2 {
        return;
    }
    if n == 2 {
        if c[1] != 0.0 {
            let x = -c[0] / c[1];
            if lo <= x && x <= hi {
                out.push(x);
            }
        }
        return;
    }
    let mut dc = [0.0; 4];
    for i in 1..n {
        dc[i - 1] = c[i] * i as f64;
    }
    let mut crit = Roots::new();
    poly_roots(&dc[..n - 1], lo, hi, xtol, &mut crit);

    let mut a = lo;
    let mut fa = horner(c, lo).0;
    if fa == 0.0 {
        out.push(lo);
    }
    for i in 0..=crit.len {
        let (b, fb) = if i < crit.len {
            let x = crit.buf[i];
            let (f, _, mag) = horner(c, x);
            let touching = f.abs() <= 16.0 * f64::EPSILON * mag;
            (x, if touching { 0.0 } else { f })
        } else {
            (hi, horner(c, hi).0)
        };
        if fa != 0.0 && fb != 0.0 && (fa < 0.0) != (fb < 0.0) {
            out.push(refine_root(c, a, b, fa, xtol));
        } else if fb == 0.0 {
            out.push(b);
        }
        a = b;
        fa = fb;
    }
}

/// The single root of `c` in `(a, b)`, where the polynomial is monotone with `p(a)` of the sign
/// of `fa` and `p(b)` of the other sign: Newton's method safeguarded by bisection ("rtsafe",
/// Numerical Recipes §9.4). Newton converges quadratically on the simple roots; whenever a step
/// would leave the bracket (e.g. near a critical point, where `p'` vanishes) it bisects instead.
fn refine_root(c: &[f64], mut a: f64, mut b: f64, fa: f64, xtol: f64) -> f64 {
    let negative_left = fa < 0.0;
    let mut x = 0.5 * (a + b);
    for _ in 0..100 {
        let (f, df, _) = horner(c, x);
        if f == 0.0 {
            break;
        }
        if (f < 0.0) == negative_left {
            a = x;
        } else {
            b = x;
        }
        let newton = x - f / df;
        let next = if newton > a && newton < b {
            newton
        } else {
            0.5 * (a + b)
        };
        let step = (next - x).abs();
        x = next;
        if step <= xtol || b - a <= xtol {
            break;
        }
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    const INF: f64 = f64::INFINITY;

    // -----------------------------------------------------------------------------------------
    // Hand-computed cases.

    #[track_caller]
    fn assert_hit(hit: Option<AnalyticHit>, t: f64, normal: DVec3) {
        let Some(hit) = hit else {
            panic!("expected a hit at t = {t}, got None");
        };
        assert!(
            (hit.t - t).abs() <= 1e-12 * t.abs().max(1.0),
            "t = {}, expected {t}",
            hit.t
        );
        assert!(
            (hit.normal - normal).length() <= 1e-9,
            "normal = {:?}, expected {normal:?}",
            hit.normal
        );
    }

    #[track_caller]
    fn assert_miss(hit: Option<AnalyticHit>) {
        assert!(hit.is_none(), "expected a miss, got {hit:?}");
    }

    fn v(x: f64, y: f64, z: f64) -> DVec3 {
        DVec3::new(x, y, z)
    }

    #[test]
    fn sphere_cases() {
        let z = DVec3::Z;
        assert_hit(sphere(v(0.0, 0.0, -3.0), z, 1.0, 0.0, INF), 2.0, -z);
        // t is in units of rd.
        assert_hit(sphere(v(0.0, 0.0, -3.0), 2.0 * z, 1.0, 0.0, INF), 1.0, -z);
        // Inside: the exit.
        assert_hit(sphere(DVec3::ZERO, z, 1.0, 0.0, INF), 1.0, z);
        // tmin past the entry: the exit.
        assert_hit(sphere(v(0.0, 0.0, -3.0), z, 1.0, 2.5, INF), 4.0, z);
        // Off-centre: x = 0.6 gives z = -0.8.
        assert_hit(
            sphere(v(0.6, 0.0, -3.0), z, 1.0, 0.0, INF),
            2.2,
            v(0.6, 0.0, -0.8),
        );
        assert_miss(sphere(v(0.0, 2.0, -3.0), z, 1.0, 0.0, INF));
        assert_miss(sphere(v(0.0, 0.0, -3.0), -z, 1.0, 0.0, INF));
        assert_miss(sphere(v(0.0, 0.0, -3.0), z, 1.0, 0.0, 1.5));
        assert_miss(sphere(v(0.0, 0.0, -3.0), z, 1.0, 0.0, 2.0)); // tmax is exclusive
        assert_miss(sphere(v(0.0, 0.0, -3.0), DVec3::ZERO, 1.0, 0.0, INF));
        // A distant origin keeps full precision.
        assert_hit(sphere(v(0.0, 0.0, -1e6), z, 1.0, 0.0, INF), 1e6 - 1.0, -z);
    }

    #[test]
    fn box_cases() {
        let h = v(1.0, 2.0, 3.0);
        let (x, y) = (DVec3::X, DVec3::Y);
        assert_hit(box_(v(-5.0, 0.0, 0.0), x, h, 0.0, INF), 4.0, -x);
        assert_hit(box_(v(-5.0, 0.0, 0.0), 4.0 * x, h, 0.0, INF), 1.0, -x);
        assert_hit(box_(DVec3::ZERO, y, h, 0.0, INF), 2.0, y);
        assert_hit(box_(DVec3::ZERO, -0.5 * y, h, 0.0, INF), 4.0, -y);
        assert_hit(box_(v(0.0, 9.0, 0.0), -y, h, 0.0, INF), 7.0, y);
        // Parallel to the x slabs, outside them: a miss however far it goes.
        assert_miss(box_(v(-5.0, 2.5, 0.0), x, h, 0.0, INF));
        assert_miss(box_(v(5.0, 0.0, 0.0), x, h, 0.0, INF));
        // Lying in the face plane y = 2 counts as touching the (closed) box.
        assert_hit(box_(v(-5.0, 2.0, 0.0), x, h, 0.0, INF), 4.0, -x);
        // Through the corner (-1, -2, -3): all slabs enter at t = 1; any of the three normals.
        let hit = box_(v(-2.0, -3.0, -4.0), v(1.0, 1.0, 1.0), h, 0.0, INF).unwrap();
        assert!((hit.t - 1.0).abs() < 1e-15);
        assert!([-DVec3::X, -DVec3::Y, -DVec3::Z].contains(&hit.normal));
        assert_miss(box_(DVec3::ZERO, x, v(1.0, -1.0, 1.0), 0.0, INF));
    }

    #[test]
    fn plane_cases() {
        let y = DVec3::Y;
        assert_hit(plane(DVec3::ZERO, 2.0 * y, y, 1.0, 0.0, INF), 0.5, y);
        // From the outside side the normal is still n.
        assert_hit(plane(v(0.0, 3.0, 0.0), -y, y, 1.0, 0.0, INF), 2.0, y);
        assert_miss(plane(v(0.0, 3.0, 0.0), y, y, 1.0, 0.0, INF));
        assert_miss(plane(DVec3::ZERO, DVec3::X, y, 1.0, 0.0, INF));
        assert_miss(plane(v(0.0, 1.0, 0.0), DVec3::X, y, 1.0, 0.0, INF));
        let n = v(1.0, 1.0, 0.0).normalize();
        assert_hit(
            plane(DVec3::ZERO, DVec3::X, n, 2f64.sqrt(), -INF, INF),
            2.0,
            n,
        );
    }

    #[test]
    fn torus_cases() {
        let (x, y, z) = (DVec3::X, DVec3::Y, DVec3::Z);
        let (big, small) = (1.0, 0.25);
        assert_hit(torus(v(-3.0, 0.0, 0.0), x, big, small, 0.0, INF), 1.75, -x);
        assert_hit(
            torus(v(-3.0, 0.0, 0.0), 2.0 * x, big, small, 0.0, INF),
            0.875,
            -x,
        );
        // Successive crossings via tmin: inner wall of the near tube, then the far tube.
        assert_hit(torus(v(-3.0, 0.0, 0.0), x, big, small, 1.8, INF), 2.25, x);
        assert_hit(torus(v(-3.0, 0.0, 0.0), x, big, small, 2.3, INF), 3.75, -x);
        assert_hit(torus(v(-3.0, 0.0, 0.0), x, big, small, 3.8, INF), 4.25, x);
        assert_miss(torus(v(-3.0, 0.0, 0.0), x, big, small, 4.3, INF));
        // Through the hole along y: a miss. Through the tube's core circle: the bottom.
        assert_miss(torus(v(0.0, -3.0, 0.0), y, big, small, 0.0, INF));
        assert_hit(torus(v(1.0, -3.0, 0.0), y, big, small, 0.0, INF), 2.75, -y);
        // Starting on the core circle, heading along z: exits where |p.xz| = 1.25.
        assert_hit(
            torus(v(1.0, 0.0, 0.0), z, big, small, 0.0, INF),
            0.75,
            v(0.8, 0.0, 0.6),
        );
        // Rays at height y just under / over the top of the tube (y = 0.25). Just under, the
        // first root is at |x| - 1 = sqrt(r^2 - y^2).
        let y_under: f64 = 0.25 - 1e-6;
        let expected = 3.0 - 1.0 - (0.0625 - y_under * y_under).sqrt();
        let hit = torus(v(-3.0, y_under, 0.0), x, big, small, 0.0, INF).unwrap();
        assert!((hit.t - expected).abs() < 1e-9, "{hit:?} vs {expected}");
        assert!(hit.normal.y > 0.99 && hit.normal.x < 0.0);
        assert_miss(torus(v(-3.0, 0.25 + 1e-6, 0.0), x, big, small, 0.0, INF));
        // Exactly tangent (double roots at x = -1 and x = 1): a touch at t = 2 or nothing.
        if let Some(hit) = torus(v(-3.0, 0.25, 0.0), x, big, small, 0.0, INF) {
            assert!((hit.t - 2.0).abs() < 1e-6, "{hit:?}");
        }
        // Diagonal in the plane y = 0 towards the centre.
        let d = v(1.0, 0.0, 1.0).normalize();
        assert_hit(torus(-3.0 * d, d, big, small, 0.0, INF), 1.75, -d);
        // Spindle torus (r > R): along x = 0.1 from below, (0.1 - 0.5)^2 + y^2 = 1.
        let y_hit = -(0.84f64).sqrt();
        assert_hit(
            torus(v(0.1, -3.0, 0.0), y, 0.5, 1.0, 0.0, INF),
            3.0 + y_hit,
            v(-0.4, y_hit, 0.0),
        );
        // ... and from inside the lemon (on the axis) the exit is the far outer surface, not the
        // lemon's own boundary at y = 0.8.
        assert_hit(
            torus(v(0.1, 0.0, 0.0), y, 0.5, 1.0, 0.0, INF),
            -y_hit,
            v(-0.4, -y_hit, 0.0),
        );
    }

    #[test]
    fn capped_cylinder_cases() {
        let (x, y, z) = (DVec3::X, DVec3::Y, DVec3::Z);
        assert_hit(
            capped_cylinder(v(0.0, 0.0, -3.0), z, 1.0, 0.5, 0.0, INF),
            2.5,
            -z,
        );
        assert_hit(
            capped_cylinder(v(0.0, -3.0, 0.0), y, 1.0, 0.5, 0.0, INF),
            2.0,
            -y,
        );
        assert_hit(
            capped_cylinder(DVec3::ZERO, 3.0 * y, 1.0, 0.5, 0.0, INF),
            1.0 / 3.0,
            y,
        );
        assert_hit(
            capped_cylinder(DVec3::ZERO, -x, 1.0, 0.5, 0.0, INF),
            0.5,
            -x,
        );
        // Parallel to the axis, outside the side wall: a miss.
        assert_miss(capped_cylinder(v(1.0, -3.0, 0.0), y, 1.0, 0.5, 0.0, INF));
        // Parallel to the caps, above them.
        assert_miss(capped_cylinder(v(-3.0, 1.5, 0.0), x, 1.0, 0.5, 0.0, INF));
        assert_hit(
            capped_cylinder(v(-3.0, 0.9, 0.0), x, 1.0, 0.5, 0.0, INF),
            2.5,
            -x,
        );
        // Slanted through the top cap: from (0, 3, -2) towards (0, 1, 0) hits the cap at t = 1.
        assert_hit(
            capped_cylinder(v(0.0, 3.0, -2.0), v(0.0, -2.0, 2.0), 1.0, 0.5, 0.0, INF),
            1.0,
            y,
        );
    }

    #[test]
    fn capsule_cases() {
        let (x, y) = (DVec3::X, DVec3::Y);
        let (a, b) = (v(0.0, -1.0, 0.0), v(0.0, 1.0, 0.0));
        assert_hit(capsule(v(0.0, -3.0, 0.0), y, a, b, 0.5, 0.0, INF), 1.5, -y);
        assert_hit(capsule(v(-3.0, 0.3, 0.0), x, a, b, 0.5, 0.0, INF), 2.5, -x);
        assert_hit(capsule(DVec3::ZERO, x, a, b, 0.5, 0.0, INF), 0.5, x);
        assert_hit(capsule(DVec3::ZERO, -y, a, b, 0.5, 0.0, INF), 1.5, -y);
        // Through the top hemisphere at height 1.3: x^2 + 0.3^2 = 0.5^2.
        assert_hit(
            capsule(v(-3.0, 1.3, 0.0), x, a, b, 0.5, 0.0, INF),
            2.6,
            v(-0.8, 0.6, 0.0),
        );
        assert_miss(capsule(v(-3.0, 1.6, 0.0), x, a, b, 0.5, 0.0, INF));
        assert_miss(capsule(v(0.6, -3.0, 0.0), y, a, b, 0.5, 0.0, INF));
        // Degenerate segment: a sphere.
        assert_hit(capsule(v(-3.0, -1.0, 0.0), x, a, a, 0.5, 0.0, INF), 2.5, -x);
        // Tilted segment along x: from the far end of the axis line.
        assert_hit(capsule(v(5.0, 0.0, 0.0), -x, -x, x, 0.5, 0.0, INF), 3.5, x);
    }

    #[test]
    fn capped_cone_cases() {
        let (x, y) = (DVec3::X, DVec3::Y);
        // Pointed at the top: radius (1 - y) / 2.
        let side = v(-0.5, 0.25, 0.0).normalize();
        assert_hit(
            capped_cone(v(-3.0, 0.0, 0.0), x, 1.0, 1.0, 0.0, 0.0, INF),
            2.5,
            side,
        );
        assert_hit(
            capped_cone(v(0.0, -3.0, 0.0), y, 1.0, 1.0, 0.0, 0.0, INF),
            2.0,
            -y,
        );
        // Straight at the apex from above.
        assert_hit(
            capped_cone(v(0.0, 3.0, 0.0), -y, 1.0, 1.0, 0.0, 0.0, INF),
            2.0,
            y,
        );
        assert_hit(
            capped_cone(DVec3::ZERO, x, 1.0, 1.0, 0.0, 0.0, INF),
            0.5,
            v(0.5, 0.25, 0.0).normalize(),
        );
        assert_hit(
            capped_cone(DVec3::ZERO, -y, 1.0, 1.0, 0.0, 0.0, INF),
            1.0,
            -y,
        );
        // Pointed at the bottom, from below: the apex.
        assert_hit(
            capped_cone(v(0.0, -3.0, 0.0), y, 1.0, 0.0, 1.0, 0.0, INF),
            2.0,
            -y,
        );
        // Frustum r = 1 at the bottom, 0.5 at the top; radius 0.75 at y = 0.
        let side = v(-1.0, 0.25, 0.0).normalize();
        assert_hit(
            capped_cone(v(-3.0, 0.0, 0.0), x, 1.0, 1.0, 0.5, 0.0, INF),
            2.25,
            side,
        );
        // Rays parallel to the axis make the side quadric's set two rays (a < 0): at x = 0.9
        // the bottom cap (radius 1) is hit; at x = 0.4 from above, the side where
        // (1 - y) / 2 = 0.4, i.e. y = 0.2.
        assert_hit(
            capped_cone(v(0.9, -3.0, 0.0), y, 1.0, 1.0, 0.0, 0.0, INF),
            2.0,
            -y,
        );
        assert_hit(
            capped_cone(v(0.4, 3.0, 0.0), -y, 1.0, 1.0, 0.0, 0.0, INF),
            2.8,
            v(0.5, 0.25, 0.0).normalize(),
        );
        assert_miss(capped_cone(v(1.2, -3.0, 0.0), y, 1.0, 1.0, 0.0, 0.0, INF));
        assert_miss(capped_cone(
            v(0.6, 0.5, -3.0),
            DVec3::Z,
            1.0,
            1.0,
            0.0,
            0.0,
            INF,
        ));
        // Equal radii: a cylinder.
        assert_hit(
            capped_cone(v(-3.0, 0.3, 0.0), x, 1.0, 0.5, 0.5, 0.0, INF),
            2.5,
            -x,
        );
        assert_miss(capped_cone(DVec3::ZERO, x, 1.0, 0.0, 0.0, 0.0, INF));
    }

    #[test]
    fn ellipsoid_cases() {
        let r = v(1.0, 2.0, 3.0);
        let (x, y, z) = (DVec3::X, DVec3::Y, DVec3::Z);
        assert_hit(ellipsoid(v(0.0, 0.0, -5.0), z, r, 0.0, INF), 2.0, -z);
        assert_hit(ellipsoid(v(-5.0, 0.0, 0.0), 2.0 * x, r, 0.0, INF), 2.0, -x);
        assert_hit(ellipsoid(DVec3::ZERO, y, r, 0.0, INF), 2.0, y);
        assert_miss(ellipsoid(v(-5.0, 2.1, 0.0), x, r, 0.0, INF));
        // (x, y) = (sqrt(0.5), sqrt(2)) lies on it; gradient (x, y / 4, 0).
        let (px, py) = (0.5f64.sqrt(), 2f64.sqrt());
        assert_hit(
            ellipsoid(v(-5.0, py, 0.0), x, r, 0.0, INF),
            5.0 - px,
            v(-px, py / 4.0, 0.0).normalize(),
        );
    }

    // -----------------------------------------------------------------------------------------
    // Randomised checks against an inside/outside predicate.

    use crate::rng::Rng;

    type Intersector = Box<dyn Fn(DVec3, DVec3, f64, f64) -> Option<AnalyticHit>>;

    /// One random instance of a primitive.
    struct Instance {
        intersect: Intersector,
        /// Negative inside, positive outside, zero on the surface and about the distance to it
        /// near the surface (an exact SDF or a bound of the same order).
        sdf: Box<dyn Fn(DVec3) -> f64>,
        /// Size of the primitive: a ball of this radius about the origin contains a bounded
        /// solid; rays are aimed at that ball and tolerances scale with it.
        scale: f64,
        /// False for the plane: its crossings are only scanned within 100 × `scale`.
        bounded: bool,
        /// Convex solids lie behind the tangent plane at every surface point.
        convex: bool,
        /// The SDF is smooth at the surface, so its gradient there is the normal's direction.
        /// (For the others that holds away from edges, where the gradient has unit length.)
        smooth: bool,
    }

    /// Chord of the line through the ball `|p| <= r`, the naive way (independent of the code
    /// under test).
    fn ball_chord(ro: DVec3, rd: DVec3, r: f64) -> Option<(f64, f64)> {
        let (a, b, c) = (rd.dot(rd), ro.dot(rd), ro.dot(ro) - r * r);
        let disc = b * b - a * c;
        (disc >= 0.0).then(|| ((-b - disc.sqrt()) / a, (-b + disc.sqrt()) / a))
    }

    /// A point inside the solid, by rejection sampling.
    fn try_point_inside(rng: &mut Rng, shape: &Instance) -> Option<DVec3> {
        (0..200)
            .map(|_| rng.in_cube(shape.scale))
            .find(|&p| (shape.sdf)(p) < 0.0)
    }

    /// A point inside the solid, or failing that one near it.
    fn point_inside(rng: &mut Rng, shape: &Instance) -> DVec3 {
        try_point_inside(rng, shape).unwrap_or_else(|| rng.in_cube(shape.scale))
    }

    fn random_axis(rng: &mut Rng) -> DVec3 {
        let axis = DVec3::AXES[rng.below(3) as usize];
        if rng.chance(0.5) { axis } else { -axis }
    }

    fn random_ray(rng: &mut Rng, shape: &Instance) -> (DVec3, DVec3, f64, f64) {
        let s = shape.scale;
        let mut ro = rng.in_cube(2.5 * s);
        let dir = match rng.below(7) {
            // Aimed at a point inside the solid: a crossing exists.
            0 | 1 => (point_inside(rng, shape) - ro)
                .try_normalize()
                .unwrap_or(DVec3::X),
            // Anywhere: mostly misses.
            2 => rng.direction_f64(),
            // Parallel to an axis (and so to faces, caps and symmetry axes) through the solid.
            3 => {
                let axis = random_axis(rng);
                ro = point_inside(rng, shape) - rng.range(0.0, 3.0) * s * axis;
                axis
            }
            // Starting inside the solid: an exit exists.
            4 | 5 => {
                ro = point_inside(rng, shape);
                rng.direction_f64()
            }
            _ => {
                ro = point_inside(rng, shape);
                random_axis(rng)
            }
        };
        let rd = dir * 10f64.powf(rng.range(-1.0, 1.0));
        let len = rd.length();
        let tmin = match rng.below(6) {
            0 => -INF,
            1 => rng.range(-2.0, 2.0) * s / len,
            _ => 0.0,
        };
        let tmax = if rng.chance(0.3) {
            tmin.max(0.0) + rng.range(0.0, 5.0) * s / len
        } else {
            INF
        };
        (ro, rd, tmin, tmax)
    }

    #[derive(Default, Debug)]
    struct Stats {
        entries: usize,
        exits: usize,
        misses: usize,
    }

    /// For each of `RAYS` random rays: a returned hit lies in `(tmin, tmax)`, on the surface, with
    /// a unit outward normal, and is a real crossing; dense sampling of the sign of the SDF along
    /// the ray finds no crossing before it (so it is the nearest), and finds none at all when
    /// `None` is returned.
    fn check_random(name: &str, seed: u64, make: impl Fn(&mut Rng) -> Instance) {
        const RAYS: usize = 5000;
        const SAMPLES: usize = 2000;
        let mut rng = Rng(seed);
        let mut stats = Stats::default();
        for ray in 0..RAYS {
            let shape = make(&mut rng);
            let s = shape.scale;
            let (ro, rd, tmin, tmax) = random_ray(&mut rng, &shape);
            let len = rd.length();
            let ctx = || format!("{name}, ray {ray}: ro {ro:?}, rd {rd:?}, t in ({tmin}, {tmax})");
            let sdf = |t: f64| (shape.sdf)(ro + t * rd);
            let sign_at = |t: f64, tol: f64| {
                let d = sdf(t);
                if d > tol {
                    1
                } else if d < -tol {
                    -1
                } else {
                    0
                }
            };
            // Evidence of a real crossing at t: points on both sides of the surface, looked for
            // on either side of t at geometrically shrinking offsets (so both broad crossings
            // and slivers thinner than the coarse grid are seen).
            let crossing_near = |t: f64, w: f64| {
                let (mut pos, mut neg) = (false, false);
                let mut off = w;
                for _ in 0..48 {
                    for x in [t - off, t + off] {
                        match sign_at(x, 1e-12 * s) {
                            1 => pos = true,
                            -1 => neg = true,
                            _ => {}
                        }
                    }
                    off *= 0.5;
                }
                pos && neg
            };

            let hit = (shape.intersect)(ro, rd, tmin, tmax);
            if let Some(h) = hit {
                assert!(h.t > tmin && h.t < tmax, "{}: {h:?} out of range", ctx());
                let p = ro + h.t * rd;
                let residual = (shape.sdf)(p);
                assert!(
                    residual.abs() <= 1e-7 * s,
                    "{}: {h:?} is off the surface by {residual}",
                    ctx()
                );
                assert!(
                    (h.normal.length() - 1.0).abs() <= 1e-9,
                    "{}: normal {:?} not unit",
                    ctx(),
                    h.normal
                );
                let out = (shape.sdf)(p + 1e-6 * s * h.normal);
                assert!(out > 0.0, "{}: {h:?}: normal points inwards ({out})", ctx());
                if shape.bounded {
                    assert!(p.length() <= 1.0001 * s, "{}: {h:?} far away", ctx());
                }
                // The normal is the surface's: the gradient of the SDF by central differences.
                let e = 1e-7 * s;
                let g = DVec3::AXES
                    .map(|a| ((shape.sdf)(p + e * a) - (shape.sdf)(p - e * a)) / (2.0 * e));
                let g = DVec3::from_array(g);
                if shape.smooth || (g.length() - 1.0).abs() < 1e-3 {
                    assert!(
                        (g.normalize() - h.normal).length() < 1e-6,
                        "{}: {h:?}: the SDF's gradient is along {g:?}",
                        ctx()
                    );
                }
                if shape.convex {
                    for _ in 0..8 {
                        let Some(q) = try_point_inside(&mut rng, &shape) else {
                            break;
                        };
                        let ahead = h.normal.dot(q - p);
                        assert!(
                            ahead <= 1e-9 * s,
                            "{}: {h:?}: {q:?} (inside) is {ahead} in front of the tangent plane",
                            ctx()
                        );
                    }
                }
                if h.normal.dot(rd) > 0.0 {
                    stats.exits += 1;
                } else {
                    stats.entries += 1;
                }
            } else {
                stats.misses += 1;
            }

            // Coarse scan of (tmin, tmax) within the ball holding every crossing.
            let radius = if shape.bounded { 1.01 * s } else { 100.0 * s };
            let Some((b0, b1)) = ball_chord(ro, rd, radius) else {
                continue;
            };
            let (lo, hi) = (b0.max(tmin), b1.min(tmax));
            if lo >= hi {
                continue;
            }
            let step = (hi - lo) / SAMPLES as f64;
            let tol = 1e-9 * s;
            let slack = 1e-6 * s / len;
            // first definite sign, the last sample still of that sign, the first of the other.
            let mut first: Option<i32> = None;
            let mut last_same = lo;
            let mut change: Option<f64> = None;
            for i in 0..=SAMPLES {
                let t = lo + step * i as f64;
                if !(t > tmin && t < tmax) {
                    continue;
                }
                let sg = sign_at(t, tol);
                if sg == 0 {
                    continue;
                }
                match first {
                    None => {
                        first = Some(sg);
                        last_same = t;
                    }
                    Some(f) if f == sg => last_same = t,
                    Some(_) => {
                        change = Some(t);
                        break;
                    }
                }
            }
            match (change, hit) {
                (Some(tc), None) => panic!("{}: missed the crossing in ({last_same}, {tc})", ctx()),
                (Some(tc), Some(h)) => {
                    assert!(
                        h.t <= tc + slack,
                        "{}: {h:?} skips the crossing in ({last_same}, {tc})",
                        ctx()
                    );
                    if h.t < last_same - slack {
                        assert!(
                            crossing_near(h.t, step),
                            "{}: {h:?} before any sign change (first at {tc})",
                            ctx()
                        );
                    }
                }
                (None, Some(h)) if h.t > lo && h.t < hi => assert!(
                    crossing_near(h.t, step),
                    "{}: {h:?} but no sign change along the ray",
                    ctx()
                ),
                _ => {}
            }
        }
        let n = RAYS / 20;
        assert!(
            stats.entries > n && stats.exits > n && stats.misses > n,
            "{name}: too few of some kind of ray to be a meaningful test: {stats:?}"
        );
    }

    #[test]
    fn sphere_random() {
        check_random("sphere", 1, |rng| {
            let r = rng.range(0.2, 2.0);
            Instance {
                intersect: Box::new(move |ro, rd, t0, t1| sphere(ro, rd, r, t0, t1)),
                sdf: Box::new(move |p| p.length() - r),
                scale: r,
                bounded: true,
                convex: true,
                smooth: true,
            }
        });
    }

    #[test]
    fn box_random() {
        check_random("box", 2, |rng| {
            let h = DVec3::new(
                rng.range(0.1, 2.0),
                rng.range(0.1, 2.0),
                rng.range(0.1, 2.0),
            );
            Instance {
                intersect: Box::new(move |ro, rd, t0, t1| box_(ro, rd, h, t0, t1)),
                sdf: Box::new(move |p| (p.abs() - h).max_element()),
                scale: h.length(),
                bounded: true,
                convex: true,
                smooth: false,
            }
        });
    }

    #[test]
    fn plane_random() {
        check_random("plane", 3, |rng| {
            let n = if rng.chance(0.2) {
                DVec3::AXES[rng.below(3) as usize]
            } else {
                rng.direction_f64()
            };
            let offset = rng.range(-1.0, 1.0);
            Instance {
                intersect: Box::new(move |ro, rd, t0, t1| plane(ro, rd, n, offset, t0, t1)),
                sdf: Box::new(move |p| n.dot(p) - offset),
                scale: 1.0,
                bounded: false,
                convex: true,
                smooth: true,
            }
        });
    }

    #[test]
    fn torus_random() {
        check_random("torus", 4, |rng| {
            let big = rng.range(0.3, 1.5);
            let small = if rng.chance(0.15) {
                big * rng.range(1.05, 2.0)
            } else {
                big * rng.range(0.05, 0.95)
            };
            Instance {
                intersect: Box::new(move |ro, rd, t0, t1| torus(ro, rd, big, small, t0, t1)),
                sdf: Box::new(move |p| (p.x.hypot(p.z) - big).hypot(p.y) - small),
                scale: big + small,
                bounded: true,
                convex: false,
                smooth: true,
            }
        });
    }

    #[test]
    fn capped_cylinder_random() {
        check_random("capped cylinder", 5, |rng| {
            let (h, r) = (rng.range(0.1, 2.0), rng.range(0.1, 2.0));
            Instance {
                intersect: Box::new(move |ro, rd, t0, t1| capped_cylinder(ro, rd, h, r, t0, t1)),
                sdf: Box::new(move |p| (p.x.hypot(p.z) - r).max(p.y.abs() - h)),
                scale: h.hypot(r),
                bounded: true,
                convex: true,
                smooth: false,
            }
        });
    }

    #[test]
    fn capsule_random() {
        check_random("capsule", 6, |rng| {
            let a = rng.in_cube(1.0);
            let b = if rng.chance(0.1) { a } else { rng.in_cube(1.0) };
            let r = rng.range(0.05, 1.0);
            Instance {
                intersect: Box::new(move |ro, rd, t0, t1| capsule(ro, rd, a, b, r, t0, t1)),
                sdf: Box::new(move |p| {
                    let ab = b - a;
                    let l2 = ab.length_squared();
                    let s = if l2 > 0.0 {
                        ((p - a).dot(ab) / l2).clamp(0.0, 1.0)
                    } else {
                        0.0
                    };
                    (p - a - s * ab).length() - r
                }),
                scale: a.length().max(b.length()) + r,
                bounded: true,
                convex: true,
                smooth: true,
            }
        });
    }

    #[test]
    fn capped_cone_random() {
        check_random("capped cone", 7, |rng| {
            let h = rng.range(0.1, 2.0);
            let mut rb = if rng.chance(0.2) {
                0.0
            } else {
                rng.range(0.0, 2.0)
            };
            let rt = match rng.below(5) {
                0 => 0.0,
                1 => rb,
                _ => rng.range(0.0, 2.0),
            };
            if rb.max(rt) == 0.0 {
                rb = 1.0;
            }
            let k = (rt - rb) / (2.0 * h);
            let c = 0.5 * (rt + rb);
            Instance {
                intersect: Box::new(move |ro, rd, t0, t1| capped_cone(ro, rd, h, rb, rt, t0, t1)),
                // Distance to the side's line in the meridian plane, or to the cap planes.
                sdf: Box::new(move |p| {
                    let side = (p.x.hypot(p.z) - (k * p.y + c)) / k.hypot(1.0);
                    side.max(p.y.abs() - h)
                }),
                scale: h.hypot(rb.max(rt)),
                bounded: true,
                convex: true,
                smooth: false,
            }
        });
    }

    #[test]
    fn ellipsoid_random() {
        check_random("ellipsoid", 8, |rng| {
            let r = DVec3::new(
                rng.range(0.1, 2.0),
                rng.range(0.1, 2.0),
                rng.range(0.1, 2.0),
            );
            Instance {
                intersect: Box::new(move |ro, rd, t0, t1| ellipsoid(ro, rd, r, t0, t1)),
                // The implicit function scaled to about a distance near the surface.
                sdf: Box::new(move |p| ((p / r).length() - 1.0) * r.min_element()),
                scale: r.max_element(),
                bounded: true,
                convex: true,
                smooth: true,
            }
        });
    }

    #[test]
    fn torus_grazing_rays() {
        // Lines tangent to the torus, pushed into the tube by a depth from 1e-3 down to 1e-13
        // of its size. Each passes through an interior point at t = l (where it is deepest
        // when the tube curves away from it), so a crossing at or before l must be reported:
        // the nearly double roots there must not be lost.
        let mut rng = Rng(9);
        for ray in 0..4000 {
            let big = rng.range(0.3, 1.5);
            let small = big * rng.range(0.05, 0.95);
            let s = big + small;
            let (theta, phi) = (
                rng.range(0.0, std::f64::consts::TAU),
                rng.range(0.0, std::f64::consts::TAU),
            );
            let n = DVec3::new(phi.cos() * theta.cos(), phi.sin(), phi.cos() * theta.sin());
            let p = DVec3::new(big * theta.cos(), 0.0, big * theta.sin()) + small * n;
            let tangent = n.any_orthonormal_pair();
            let angle = rng.range(0.0, std::f64::consts::TAU);
            let dir = angle.cos() * tangent.0 + angle.sin() * tangent.1;
            let depth = s * 10f64.powf(rng.range(-13.0, -3.0));
            let l = 3.0 * s;
            let ro = p - depth * n - l * dir;
            let hit = torus(ro, dir, big, small, 0.0, INF);
            let Some(h) = hit else {
                panic!("ray {ray}: no hit, R {big} r {small} p {p:?} dir {dir:?} depth {depth}");
            };
            let q = ro + h.t * dir;
            let residual = (q.x.hypot(q.z) - big).hypot(q.y) - small;
            assert!(
                h.t <= l + 1e-9 * s && residual.abs() <= 1e-9 * s,
                "ray {ray}: {h:?} (residual {residual}), interior point at {l}, depth {depth}"
            );
        }
    }

    #[test]
    fn poly_roots_finds_close_and_double_roots() {
        // (x - 1)^2 (x - 2) (x - 2.0001): a double root and a close pair.
        let roots_of = |r: [f64; 4]| {
            // Ascending coefficients of prod (x - r_i).
            let mut c = [1.0, 0.0, 0.0, 0.0, 0.0];
            for (deg, &ri) in r.iter().enumerate() {
                for j in (0..=deg + 1).rev() {
                    let lower = if j > 0 { c[j - 1] } else { 0.0 };
                    c[j] = lower - ri * c[j];
                }
            }
            let mut out = Roots::new();
            poly_roots(&c, -10.0, 10.0, 1e-15, &mut out);
            out
        };
        let out = roots_of([1.0, 1.0, 2.0, 2.0 + 1e-4]);
        let got = out.as_slice();
        assert_eq!(got.len(), 3, "{got:?}");
        assert!((got[0] - 1.0).abs() < 1e-7);
        assert!(
            (got[1] - 2.0).abs() < 1e-9 && (got[2] - 2.0001).abs() < 1e-9,
            "{got:?}"
        );
        let out = roots_of([-3.0, -1.0, 0.5, 4.0]);
        let got = out.as_slice();
        assert_eq!(got.len(), 4, "{got:?}");
        for (g, e) in got.iter().zip([-3.0, -1.0, 0.5, 4.0]) {
            assert!((g - e).abs() < 1e-13, "{got:?}");
        }
    }
}
