//! Polygon triangulation: ear clipping in the polygon's best-fit plane.

use glam::{DVec2, DVec3, Vec3};

/// Polygons with more corners than this are fanned: ear clipping costs O(n²) and more.
pub(super) const MAX_EAR_CLIP: usize = 1024;

/// Splits a polygon, corners in order, into n − 2 triangles of corner indices with the
/// polygon's winding. The corners are projected onto the plane of the polygon's Newell normal
/// and ears are clipped there (strictly convex ears containing no other corner first, then
/// degenerate ones), so concave polygons are handled correctly. Degenerate input (zero area,
/// non-finite coordinates, more than [`MAX_EAR_CLIP`] corners) and polygons where no ear can
/// be found (self-intersecting ones) are fanned from their first remaining corner. Fewer than
/// three corners give no triangle.
pub(super) fn triangulate(points: &[Vec3], out: &mut Vec<[usize; 3]>) {
    let n = points.len();
    if n < 3 {
        return;
    }
    if n == 3 {
        out.push([0, 1, 2]);
        return;
    }
    if n > MAX_EAR_CLIP {
        fan(&(0..n).collect::<Vec<_>>(), out);
        return;
    }
    // Newell's normal: the area-weighted normal of a (possibly non-planar) polygon.
    let p: Vec<DVec3> = points.iter().map(|q| q.as_dvec3()).collect();
    let mut normal = DVec3::ZERO;
    for i in 0..n {
        let (a, b) = (p[i], p[(i + 1) % n]);
        normal.x += (a.y - b.y) * (a.z + b.z);
        normal.y += (a.z - b.z) * (a.x + b.x);
        normal.z += (a.x - b.x) * (a.y + b.y);
    }
    let Some(normal) = normal.try_normalize() else {
        fan(&(0..n).collect::<Vec<_>>(), out);
        return;
    };
    // (u, v, normal) is right-handed, so the polygon winds counter-clockwise in (u, v).
    let u = normal.any_orthonormal_vector();
    let v = normal.cross(u);
    let q: Vec<DVec2> = p
        .iter()
        .map(|&x| DVec2::new((x - p[0]).dot(u), (x - p[0]).dot(v)))
        .collect();
    let (lo, hi) = q
        .iter()
        .fold((DVec2::INFINITY, DVec2::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        });
    let extent = (hi - lo).max_element();
    let eps = 1e-12 * extent * extent;

    let mut ring: Vec<usize> = (0..n).collect();
    while ring.len() > 3 {
        let m = ring.len();
        let corner = |k: usize| (ring[(k + m - 1) % m], ring[k], ring[(k + 1) % m]);
        let is_ear = |k: usize, strict: bool| {
            let (a, b, c) = corner(k);
            let turn = cross(q[b] - q[a], q[c] - q[b]);
            if strict {
                turn > eps
                    && !ring.iter().any(|&j| {
                        j != a
                            && j != b
                            && j != c
                            && q[j] != q[a]
                            && q[j] != q[b]
                            && q[j] != q[c]
                            && in_triangle(q[j], q[a], q[b], q[c], eps)
                    })
            } else {
                turn >= -eps
            }
        };
        let ear = (0..m)
            .find(|&k| is_ear(k, true))
            .or_else(|| (0..m).find(|&k| is_ear(k, false)));
        match ear {
            Some(k) => {
                let (a, b, c) = corner(k);
                out.push([a, b, c]);
                ring.remove(k);
            }
            None => {
                fan(&ring, out);
                return;
            }
        }
    }
    out.push([ring[0], ring[1], ring[2]]);
}

/// Fan triangles (r₀, rᵢ, rᵢ₊₁) over `ring`.
fn fan(ring: &[usize], out: &mut Vec<[usize; 3]>) {
    for i in 1..ring.len().saturating_sub(1) {
        out.push([ring[0], ring[i], ring[i + 1]]);
    }
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Whether `p` lies inside or on the counter-clockwise triangle (a, b, c).
fn in_triangle(p: DVec2, a: DVec2, b: DVec2, c: DVec2, eps: f64) -> bool {
    cross(b - a, p - a) >= -eps && cross(c - b, p - b) >= -eps && cross(a - c, p - c) >= -eps
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(points: &[Vec3], tris: &[[usize; 3]], normal: Vec3) -> f32 {
        tris.iter()
            .map(|t| {
                let n = (points[t[1]] - points[t[0]]).cross(points[t[2]] - points[t[0]]);
                0.5 * n.dot(normal)
            })
            .sum()
    }

    #[test]
    fn concave_l_shape_is_covered_exactly() {
        // Starting at (2, 1): a fan from there would leave the L.
        let pts: Vec<Vec3> = [(2., 1.), (1., 1.), (1., 2.), (0., 2.), (0., 0.), (2., 0.)]
            .iter()
            .map(|&(x, y)| Vec3::new(x, y, 0.0))
            .collect();
        for rot in 0..pts.len() {
            let mut p = pts.clone();
            p.rotate_left(rot);
            let mut tris = Vec::new();
            triangulate(&p, &mut tris);
            assert_eq!(tris.len(), 4);
            for t in &tris {
                let n = (p[t[1]] - p[t[0]]).cross(p[t[2]] - p[t[0]]);
                assert!(
                    n.z > 0.0,
                    "rotation {rot}: triangle {t:?} flipped or degenerate"
                );
            }
            assert!((area(&p, &tris, Vec3::Z) - 3.0).abs() < 1e-5);
        }
    }

    #[test]
    fn degenerate_and_tiny_inputs() {
        let mut tris = Vec::new();
        triangulate(&[Vec3::ZERO; 5], &mut tris);
        assert_eq!(tris.len(), 3);
        tris.clear();
        triangulate(&[Vec3::ZERO, Vec3::X], &mut tris);
        assert!(tris.is_empty());
        tris.clear();
        triangulate(&[Vec3::NAN, Vec3::X, Vec3::Y, Vec3::ONE], &mut tris);
        assert_eq!(tris.len(), 2);
    }
}
