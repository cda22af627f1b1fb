//! Conservative bounds of an SDF node's surface, in the node's own space.

use super::LowerError;
use crate::geom::Aabb;
use crate::sdf::node::SdfNode;
use glam::{Affine3A, Quat, Vec3};

/// Conservative bounds of a node's surface in its own space.
pub fn bounds(node: &SdfNode) -> Result<Aabb, LowerError> {
    use SdfNode::*;
    let child = |n: &SdfNode| bounds(n);
    Ok(match node {
        Sphere { radius } => Aabb::symmetric(Vec3::splat(radius.0)),
        Cuboid { half_extents } | RoundBox { half_extents, .. } => Aabb::symmetric(half_extents.0),
        Plane { .. } => Aabb::INFINITE,
        Torus { major, minor } => {
            let r = major.0 + minor.0;
            Aabb::symmetric(Vec3::new(r, minor.0, r))
        }
        Cylinder {
            half_height,
            radius,
        } => Aabb::symmetric(Vec3::new(radius.0, half_height.0, radius.0)),
        Cone {
            half_height,
            bottom_radius,
            top_radius,
        } => {
            let r = bottom_radius.0.max(top_radius.0);
            Aabb::symmetric(Vec3::new(r, half_height.0, r))
        }
        Capsule { a, b, radius } => Aabb::new(a.0.min(b.0), a.0.max(b.0)).expand(radius.0),
        Ellipsoid { radii } => Aabb::symmetric(radii.0),
        Octahedron { size } => Aabb::symmetric(Vec3::splat(size.0)),
        HexPrism {
            radius,
            half_length,
        } => {
            // circumradius of a hexagon with apothem r is 2r/√3
            let c = radius.0 * 2.0 / 3f32.sqrt();
            Aabb::symmetric(Vec3::new(c, c, half_length.0))
        }
        Union(v) => v
            .iter()
            .try_fold(Aabb::EMPTY, |acc, n| Ok(acc.union(&child(n)?)))?,
        Intersection(v) => v
            .iter()
            .try_fold(Aabb::INFINITE, |acc, n| Ok(acc.intersection(&child(n)?)))?,
        Subtraction { base, .. } | SmoothSubtraction { base, .. } => child(base)?,
        // smin(a, b) ≥ min(a, b) − k/4, so the blend grows each child by at most k/4.
        SmoothUnion { k, shapes } => shapes
            .iter()
            .try_fold(Aabb::EMPTY, |acc, n| Ok(acc.union(&child(n)?)))?
            .expand(k.0 * 0.25),
        SmoothIntersection { shapes, .. } => shapes
            .iter()
            .try_fold(Aabb::INFINITE, |acc, n| Ok(acc.intersection(&child(n)?)))?,
        Round { radius, shape } => child(shape)?.expand(radius.0),
        Onion { thickness, shape } => child(shape)?.expand(thickness.0),
        Transform { .. } => child_of_transform(node)?,
        Scale { factors, shape } => {
            let c = child(shape)?;
            Aabb::new(c.min * factors.0, c.max * factors.0)
        }
        Repeat { period, shape } => {
            let c = child(shape)?;
            let p = [period.0.0, period.1.0, period.2.0];
            let mut out = c;
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
            let c = child(shape)?;
            let n = Vec3::new(
                copies_each_side.0 as f32,
                copies_each_side.1 as f32,
                copies_each_side.2 as f32,
            );
            Aabb::new(c.min - n * period.0, c.max + n * period.0)
        }
        Twist { shape, .. } => {
            let c = finite_child(shape, "Twist")?;
            let r = max_radius(&c, [0, 2]);
            Aabb::new(Vec3::new(-r, c.min.y, -r), Vec3::new(r, c.max.y, r))
        }
        Bend { shape, .. } => {
            let c = finite_child(shape, "Bend")?;
            let r = max_radius(&c, [0, 1]);
            Aabb::new(Vec3::new(-r, -r, c.min.z), Vec3::new(r, r, c.max.z))
        }
        Implicit { half_extents, .. } => Aabb::symmetric(half_extents.0),
        Material { shape, .. } => child(shape)?,
    })
}

fn child_of_transform(node: &SdfNode) -> Result<Aabb, LowerError> {
    let SdfNode::Transform { shape, .. } = node else {
        unreachable!("called on Transform nodes only")
    };
    let (m, _) = transform_of(node);
    Ok(bounds(shape)?.transformed(&m))
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
