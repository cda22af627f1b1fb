//! Conservative bounds of an SDF node's surface, in the node's own space.
//!
//! What a parent needs of a child is not only where the child's surface lies but where its
//! field is at most some level c ≥ 0: `Round(r)` keeps f ≤ r, `Onion(t)` keeps |f| ≤ t, a
//! smooth union reaches below the smallest child by its blend. For an exact distance that is
//! the surface's box grown by c; for a distance *bound* (|f| ≤ distance) the field may stay
//! below c much farther out — a rounded flat ellipsoid, or a rounded non-uniform scale, pokes
//! out of its children's boxes grown by r — so every rule below is for the sublevel set
//! {f ≤ c} and passes its own level down.

use super::LowerError;
use crate::geom::Aabb;
use crate::sdf::node::SdfNode;
use glam::{Affine3A, Quat, Vec3};

/// Conservative bounds of a node's surface (and the solid inside it) in its own space.
pub fn bounds(node: &SdfNode) -> Result<Aabb, LowerError> {
    sublevel(node, 0.0)
}

/// A box holding every point where the node's field is at most `level` (≥ 0).
fn sublevel(node: &SdfNode, level: f32) -> Result<Aabb, LowerError> {
    use SdfNode::*;
    let c = level;
    // an exact field: the surface's box grown by the level (f ≤ c within c of the surface)
    let exact = |half_extents: Vec3| Aabb::symmetric(half_extents + Vec3::splat(c));
    Ok(match node {
        Sphere { radius } => exact(Vec3::splat(radius.0)),
        Cuboid { half_extents } | RoundBox { half_extents, .. } => exact(half_extents.0),
        Plane { .. } => Aabb::INFINITE,
        Torus { major, minor } => {
            let r = major.0 + minor.0;
            exact(Vec3::new(r, minor.0, r))
        }
        Cylinder {
            half_height,
            radius,
        } => exact(Vec3::new(radius.0, half_height.0, radius.0)),
        Cone {
            half_height,
            bottom_radius,
            top_radius,
        } => {
            let r = bottom_radius.0.max(top_radius.0);
            exact(Vec3::new(r, half_height.0, r))
        }
        Capsule { a, b, radius } => Aabb::new(a.0.min(b.0), a.0.max(b.0)).expand(radius.0 + c),
        Ellipsoid { radii } => {
            // f = max((|p/r| − 1)·min(r), |p| − max(r)) ≤ c needs |p_i|/r_i ≤ |p/r| ≤
            // 1 + c/min(r) and |p_i| ≤ |p| ≤ max(r) + c: along a short axis the first term
            // reaches farther than r_i + c (it underestimates the distance there).
            let (lo, hi) = (radii.0.min_element(), radii.0.max_element());
            Aabb::symmetric((radii.0 * (1.0 + c / lo)).min(Vec3::splat(hi + c)))
        }
        Octahedron { size } => exact(Vec3::splat(size.0)),
        HexPrism {
            radius,
            half_length,
        } => {
            // circumradius of a hexagon with apothem r is 2r/√3
            let r = radius.0 * 2.0 / 3f32.sqrt();
            exact(Vec3::new(r, r, half_length.0))
        }
        // min ≤ c where some child is
        Union(v) => v.iter().try_fold(Aabb::EMPTY, |acc, n| {
            Ok::<_, LowerError>(acc.union(&sublevel(n, c)?))
        })?,
        // max ≤ c (and the smooth maximum, which is ≥ max) where every child is
        Intersection(v) | SmoothIntersection { shapes: v, .. } => {
            v.iter().try_fold(Aabb::INFINITE, |acc, n| {
                Ok::<_, LowerError>(acc.intersection(&sublevel(n, c)?))
            })?
        }
        // max(base, −cut) and its smooth form are ≥ base
        Subtraction { base, .. } | SmoothSubtraction { base, .. } => sublevel(base, c)?,
        SmoothUnion { k, shapes } => {
            let below = smooth_union_deficit(k.0, shapes.len());
            shapes.iter().try_fold(Aabb::EMPTY, |acc, n| {
                Ok::<_, LowerError>(acc.union(&sublevel(n, c + below)?))
            })?
        }
        Round { radius, shape } => sublevel(shape, c + radius.0)?,
        // |f| − t ≤ c needs f ≤ c + t
        Onion { thickness, shape } => sublevel(shape, c + thickness.0)?,
        Transform { shape, .. } => {
            // s·f(M⁻¹p) ≤ c where f ≤ c/s
            let (m, s) = transform_of(node);
            sublevel(shape, c / s)?.transformed(&m)
        }
        Scale { factors, shape } => {
            // f(p/s)·min(s) ≤ c where f ≤ c/min(s), at p = s·q
            let child = sublevel(shape, c / factors.0.min_element())?;
            Aabb::new(child.min * factors.0, child.max * factors.0)
        }
        Repeat { period, shape } => {
            // the copies, and the cap's slab (≥ the distance to the region of every copy)
            let mut out = sublevel(shape, c)?.union(&bounds(shape)?.expand(c));
            let p = [period.0.0, period.1.0, period.2.0];
            for (i, &pi) in p.iter().enumerate() {
                if pi > 0.0 {
                    out.min[i] = f32::NEG_INFINITY;
                    out.max[i] = f32::INFINITY;
                }
            }
            out
        }
        RepeatLimited {
            period,
            copies_each_side,
            shape,
        } => {
            let n = Vec3::new(
                copies_each_side.0 as f32,
                copies_each_side.1 as f32,
                copies_each_side.2 as f32,
            );
            let copies = |b: Aabb| Aabb::new(b.min - n * period.0, b.max + n * period.0);
            copies(sublevel(shape, c)?).union(&copies(bounds(shape)?).expand(c))
        }
        // g = max(f(π(p))/λ, d_R) ≥ d_R, the distance to the region R the box holds
        Twist { shape, .. } => {
            let b = finite_child(shape, "Twist")?;
            let r = max_radius(&b, [0, 2]);
            Aabb::new(Vec3::new(-r, b.min.y, -r), Vec3::new(r, b.max.y, r)).expand(c)
        }
        Bend { shape, .. } => {
            let b = finite_child(shape, "Bend")?;
            let r = max_radius(&b, [0, 1]);
            Aabb::new(Vec3::new(-r, -r, b.min.z), Vec3::new(r, r, b.max.z)).expand(c)
        }
        Implicit { half_extents, .. } => exact(half_extents.0),
        Material { shape, .. } => sublevel(shape, c)?,
    })
}

/// How far a smooth union of `n` shapes with blend `k` can fall below its smallest child.
/// One polynomial smooth minimum falls at most k/4 below min(a, b) (where a = b); the chain
/// smin(smin(a, b), c)… falls further, at most d_{j+1} = (k + d_j)²/4k below the smallest
/// child so far: smin is non-decreasing in each argument, so its worst case is x = m − d_j
/// against y = m, where it gives m − (k + d_j)²/4k. The sequence rises to k, never above.
fn smooth_union_deficit(k: f32, n: usize) -> f32 {
    if k <= 0.0 {
        return 0.0;
    }
    let mut d = 0.0f32;
    for _ in 1..n {
        d = ((k + d) * (k + d) / (4.0 * k)).min(k);
    }
    d
}

fn finite_child(shape: &SdfNode, what: &'static str) -> Result<Aabb, LowerError> {
    let c = bounds(shape)?;
    if c.is_finite() && !c.is_empty() {
        Ok(c)
    } else {
        Err(LowerError {
            path: Vec::new(),
            message: format!(
                "{what} needs a bounded child (its Lipschitz correction depends on the child's \
                 size), but `{}` is unbounded",
                shape.kind()
            ),
        })
    }
}

/// Largest distance from the axis orthogonal to lanes `axes` over the box corners.
fn max_radius(b: &Aabb, axes: [usize; 2]) -> f32 {
    b.corners()
        .iter()
        .map(|c| (c[axes[0]] * c[axes[0]] + c[axes[1]] * c[axes[1]]).sqrt())
        .fold(0.0, f32::max)
}

/// The object-to-parent affine map of a `Transform` node and its uniform scale.
pub fn transform_of(node: &SdfNode) -> (Affine3A, f32) {
    let SdfNode::Transform {
        translate,
        rotate,
        scale,
        ..
    } = node
    else {
        return (Affine3A::IDENTITY, 1.0);
    };
    let r = rotate.map(|r| r.0).unwrap_or(Vec3::ZERO);
    let q = Quat::from_rotation_z(r.z.to_radians())
        * Quat::from_rotation_y(r.y.to_radians())
        * Quat::from_rotation_x(r.x.to_radians());
    let s = scale.map(|s| s.0).unwrap_or(1.0);
    let t = translate.map(|t| t.0).unwrap_or(Vec3::ZERO);
    (
        Affine3A::from_scale_rotation_translation(Vec3::splat(s), q, t),
        s,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sdf::conformance::{distance_tape, parse_node, points_on_faces};

    /// A point just outside the node's bounds where its lowered field is ≤ 0 (the surface
    /// pokes out), from a 64 × 64 grid over each face of the bounds grown by a hair.
    fn escape(src: &str) -> Option<Vec3> {
        let node = parse_node(src);
        let b = bounds(&node).unwrap_or_else(|e| panic!("{src}: {}", e.message));
        assert!(b.is_finite(), "{src}: unbounded");
        let b = b.expand(1e-4 * (1.0 + (b.max - b.min).max_element()));
        let tape = distance_tape(&node);
        points_on_faces(b, 64).find(|&p| tape.eval(p) <= 0.0)
    }

    #[test]
    fn rounding_a_distance_bound_keeps_the_surface_inside_the_bounds() {
        // The ellipsoid's field underestimates along its short axes, so f ≤ r reaches past
        // each half-extent + r there; a non-uniform scale's f(p/s)·min(s) likewise.
        for src in [
            "Round(radius: 0.08, shape: Ellipsoid(radii: (0.08, 0.125, 0.15)))",
            "Onion(thickness: 0.1, shape: Ellipsoid(radii: (0.1, 0.3, 0.6)))",
            "Round(radius: 0.1, shape: Scale(factors: (2, 1, 0.7), shape: Sphere(radius: 0.5)))",
            "SmoothUnion(k: 0.3, shapes: [Ellipsoid(radii: (0.1, 0.4, 0.2)), \
             Transform(translate: (0, 0.3, 0), shape: Ellipsoid(radii: (0.3, 0.1, 0.2)))])",
        ] {
            assert_eq!(
                escape(src),
                None,
                "{src} pokes out of {:?}",
                bounds(&parse_node(src))
            );
        }
    }

    #[test]
    fn a_smooth_union_of_many_shapes_keeps_its_blend_inside_the_bounds() {
        // Where n children meet, the chained smooth minimum falls further below the
        // smallest child than one blend's k/4: coincident spheres inflate toward r + k.
        for n in 2..=6 {
            let spheres = vec!["Sphere(radius: 0.2)"; n].join(", ");
            let src = format!("SmoothUnion(k: 1.0, shapes: [{spheres}])");
            assert_eq!(escape(&src), None, "{src}");
            // and the bound stays within the deficit's limit, k
            let b = bounds(&parse_node(&src)).unwrap_or_else(|e| panic!("{}", e.message));
            assert!(b.max.x <= 0.2 + 1.0 + 1e-6, "{n} spheres: {b:?}");
        }
    }

    #[test]
    fn the_smooth_union_deficit_is_that_of_equal_children() {
        // smin(…smin(v, v)…, v) with n equal children falls exactly d_n below v.
        use crate::sdf::conformance::Rng;
        let mut rng = Rng::new(7);
        for n in 2..=8 {
            let k = 0.5;
            let spheres = vec!["Sphere(radius: 1.0)"; n].join(", ");
            let tape = distance_tape(&parse_node(&format!(
                "SmoothUnion(k: {k}, shapes: [{spheres}])"
            )));
            let p = rng.direction() * 2.0;
            let fallen = (p.length() - 1.0) - tape.eval(p);
            let d = smooth_union_deficit(k, n);
            assert!((fallen - d).abs() < 1e-5, "{n}: fell {fallen}, deficit {d}");
        }
    }
}
