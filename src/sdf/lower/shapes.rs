//! Primitive distance formulas and the CSG combinations, after Quilez's catalogue
//! ("distance functions", iquilezles.org, 2008–2024).

use super::emit::{Emit, V3};
use crate::sdf::ssa::{Builder, M, V};
use glam::Vec3;

/// A lowered subtree: its distance and its material.
#[derive(Clone, Copy)]
pub struct Out {
    /// The distance (or bound).
    pub d: V,
    /// The blended material.
    pub m: M,
}

impl Out {
    /// A primitive: distance `d` painted with material `mat`.
    pub fn leaf(b: &mut Builder, d: V, mat: u32) -> Out {
        Out {
            d,
            m: b.mat_load(mat),
        }
    }
}

/// min(x, y), with the material of the nearer shape.
pub fn union(b: &mut Builder, x: Out, y: Out) -> Out {
    let d = b.min(x.d, y.d);
    // h = 1 picks y when x is farther.
    let diff = b.sub(x.d, y.d);
    let (one, zero) = (b.k(1.0), b.k(0.0));
    let h = b.pick(diff, one, zero);
    Out {
        d,
        m: b.mat_mix(x.m, y.m, h),
    }
}

/// max(x, y), with the material of the farther shape.
pub fn intersection(b: &mut Builder, x: Out, y: Out) -> Out {
    let d = b.max(x.d, y.d);
    let diff = b.sub(y.d, x.d);
    let (one, zero) = (b.k(1.0), b.k(0.0));
    let h = b.pick(diff, one, zero);
    Out {
        d,
        m: b.mat_mix(x.m, y.m, h),
    }
}

/// Quilez's polynomial smooth minimum, f = x(1−h) + y·h − k·h(1−h) with
/// h = clamp(½ + ½(x−y)/k, 0, 1); the same h blends the materials. Written in this form (not
/// x + (y − x)·h) because it is exact where the blend is decided: with h = 1, x·0 + y·1 − k·0
/// is y to the last bit, so the specialised tape of a region where the children differ by more
/// than k (which keeps only y) computes what the whole tape computes there.
pub fn smooth_min(b: &mut Builder, x: Out, y: Out, k: f32) -> Out {
    if k <= 0.0 {
        return union(b, x, y);
    }
    let diff = b.sub(x.d, y.d);
    let t = b.mul_k(diff, 0.5 / k);
    let t = b.add_k(t, 0.5);
    let h = b.clamp_k(t, 0.0, 1.0);
    let one_minus = b.rsub_k(1.0, h);
    let xs = b.mul(x.d, one_minus);
    let ys = b.mul(y.d, h);
    let mix = b.add(xs, ys);
    let kh = b.mul_k(h, k);
    let bump = b.mul(kh, one_minus);
    Out {
        d: b.sub(mix, bump),
        m: b.mat_mix(x.m, y.m, h),
    }
}

/// Smooth maximum: −smin(−a, −b, k).
pub fn smooth_max(b: &mut Builder, x: Out, y: Out, k: f32) -> Out {
    if k <= 0.0 {
        return intersection(b, x, y);
    }
    let nx = Out {
        d: b.neg(x.d),
        m: x.m,
    };
    let ny = Out {
        d: b.neg(y.d),
        m: y.m,
    };
    let s = smooth_min(b, nx, ny, k);
    Out {
        d: b.neg(s.d),
        m: s.m,
    }
}

/// Quilez sdBox: exact distance to the box [−h, h].
pub fn box_distance(b: &mut Builder, p: V3, h: Vec3) -> V {
    let a = b.v_abs(p);
    let q = b.v_sub_k(a, h);
    let qp = b.v_max_k(q, 0.0);
    let outside = b.length(&qp.0);
    let m = b.max_of(&q.0);
    let inside = b.min_k(m, 0.0);
    b.add(outside, inside)
}

/// Exact distance to a rectangle of half-sizes (hx, hy) in a 2-D plane, from the
/// coordinates' offsets d = |q| − h already formed: min(max(dx, dy), 0) + |max(d, 0)|.
fn rectangle_from_offsets(b: &mut Builder, dx: V, dy: V) -> V {
    let m = b.max(dx, dy);
    let inside = b.min_k(m, 0.0);
    let px = b.max_k(dx, 0.0);
    let py = b.max_k(dy, 0.0);
    let outside = b.length(&[px, py]);
    b.add(inside, outside)
}

/// Quilez sdTorus in the xz-plane: exact.
pub fn torus(b: &mut Builder, p: V3, major: f32, minor: f32) -> V {
    let l = b.length(&[p.x(), p.z()]);
    let qx = b.sub_k(l, major);
    let lq = b.length(&[qx, p.y()]);
    b.sub_k(lq, minor)
}

/// Quilez sdCappedCylinder along y: exact.
pub fn cylinder_y(b: &mut Builder, p: V3, h: f32, r: f32) -> V {
    let l = b.length(&[p.x(), p.z()]);
    let dx = b.sub_k(l, r);
    let ay = b.abs(p.y());
    let dy = b.sub_k(ay, h);
    rectangle_from_offsets(b, dx, dy)
}

/// Quilez sdCappedCone (exact): r1 at y = −h, r2 at y = +h.
pub fn capped_cone(b: &mut Builder, p: V3, h: f32, r1: f32, r2: f32) -> V {
    let qx = b.length(&[p.x(), p.z()]);
    let qy = p.y();
    let k1 = [r2, h];
    let k2 = [r2 - r1, 2.0 * h];
    // ca = (q.x − min(q.x, q.y < 0 ? r1 : r2), |q.y| − h)
    let nqy = b.neg(qy);
    let (c1, c2) = (b.k(r1), b.k(r2));
    let rsel = b.pick(nqy, c1, c2);
    let mq = b.min(qx, rsel);
    let cax = b.sub(qx, mq);
    let aqy = b.abs(qy);
    let cay = b.sub_k(aqy, h);
    // cb = q − k1 + k2·clamp(dot(k1 − q, k2)/dot(k2, k2), 0, 1)
    let kqx = b.sub_k(qx, k1[0]);
    let kqy = b.sub_k(qy, k1[1]);
    let tx = b.mul_k(kqx, -k2[0]);
    let ty = b.mul_k(kqy, -k2[1]);
    let dk = b.add(tx, ty);
    let t = b.mul_k(dk, 1.0 / (k2[0] * k2[0] + k2[1] * k2[1]));
    let t = b.clamp_k(t, 0.0, 1.0);
    let ox = b.mul_k(t, k2[0]);
    let oy = b.mul_k(t, k2[1]);
    let cbx = b.add(kqx, ox);
    let cby = b.add(kqy, oy);
    // s = (cb.x < 0 && ca.y < 0) ? −1 : 1
    let m = b.max(cbx, cay);
    let (one, minus) = (b.k(1.0), b.k(-1.0));
    let s = b.pick(m, one, minus);
    let la = b.length(&[cax, cay]);
    let lb = b.length(&[cbx, cby]);
    let dmin = b.min(la, lb);
    b.mul(s, dmin)
}

/// Quilez sdCapsule: distance to the closest point of the segment a–b, minus r.
pub fn capsule(b: &mut Builder, p: V3, a: Vec3, e: Vec3, r: f32) -> V {
    let ba = e - a;
    let pa = b.v_sub_k(p, a);
    if ba.length_squared() < 1e-12 {
        let l = b.length(&pa.0);
        return b.sub_k(l, r);
    }
    let t = b.dot_k(pa, ba);
    let t = b.mul_k(t, 1.0 / ba.length_squared());
    let h = b.clamp_k(t, 0.0, 1.0);
    let diff = V3(std::array::from_fn(|i| {
        let o = b.mul_k(h, ba[i]);
        b.sub(pa.at(i), o)
    }));
    let l = b.length(&diff.0);
    b.sub_k(l, r)
}

/// A guaranteed bound for the ellipsoid: (|p/r| − 1)·min(r) has |∇| ≤ 1 (the gradient is
/// min(r)·|p/r²|/|p/r| ≤ 1), vanishes exactly on the surface, and its max with the bounding
/// sphere's distance |p| − max(r) stays a bound while being tight far away. Quilez's
/// k0(k0−1)/k1 estimate looks better but over-estimates by up to ~10% near the tips of
/// elongated ellipsoids (the conformance suite measures it).
pub fn ellipsoid(b: &mut Builder, p: V3, r: Vec3) -> V {
    let pr = b.v_div_k(p, r);
    let k0 = b.length(&pr.0);
    let k0m = b.sub_k(k0, 1.0);
    let near = b.mul_k(k0m, r.min_element());
    let l = b.length(&p.0);
    let far = b.sub_k(l, r.max_element());
    b.max(near, far)
}

/// Quilez sdOctahedron, exact form, with the branches turned into selects.
pub fn octahedron(b: &mut Builder, p: V3, s: f32) -> V {
    let ap = b.v_abs(p);
    let sum = b.dot_k(ap, Vec3::ONE);
    let m = b.sub_k(sum, s);
    // lane i > 0 ⇔ 3·p_i < m
    let cond: [V; 3] = std::array::from_fn(|i| {
        let t = b.mul_k(ap.at(i), 3.0);
        b.sub(m, t)
    });
    let rot = |i: usize| V3([ap.at(i % 3), ap.at((i + 1) % 3), ap.at((i + 2) % 3)]);
    let (q1, q2, q3) = (rot(0), rot(1), rot(2));
    let q = V3(std::array::from_fn(|i| {
        let inner = b.pick(cond[1], q2.at(i), q3.at(i));
        b.pick(cond[0], q1.at(i), inner)
    }));
    let dzy = b.sub(q.z(), q.y());
    let kk = b.add_k(dzy, s);
    let kk = b.mul_k(kk, 0.5);
    let k = b.clamp_k(kk, 0.0, s);
    let ks = b.sub_k(k, s);
    let vy = b.add(q.y(), ks);
    let vz = b.sub(q.z(), k);
    let exact = b.length(&[q.x(), vy, vz]);
    let any = b.max_of(&cond);
    let flat = b.mul_k(m, 0.577_350_26);
    b.pick(any, exact, flat)
}

/// Quilez sdHexPrism (exact): apothem r in the xy-plane, half-length hz along z.
pub fn hex_prism(b: &mut Builder, p: V3, r: f32, hz: f32) -> V {
    const K: Vec3 = Vec3::new(-0.866_025_4, 0.5, 0.577_350_26);
    let ap = b.v_abs(p);
    let dk = b.dot_k(ap, Vec3::new(K.x, K.y, 0.0));
    let dk = b.min_k(dk, 0.0);
    // p.xy −= 2·min(dot(k.xy, p.xy), 0)·k.xy
    let ox = b.mul_k(dk, -2.0 * K.x);
    let oy = b.mul_k(dk, -2.0 * K.y);
    let p2x = b.add(ox, ap.x());
    let p2y = b.add(oy, ap.y());
    let cx = b.clamp_k(p2x, -K.z * r, K.z * r);
    let wx = b.sub(p2x, cx);
    let wy = b.sub_k(p2y, r);
    let lw = b.length(&[wx, wy]);
    let (one, minus) = (b.k(1.0), b.k(-1.0));
    let sgn = b.pick(wy, one, minus);
    let dx = b.mul(lw, sgn);
    let dy = b.sub_k(ap.z(), hz);
    rectangle_from_offsets(b, dx, dy)
}
