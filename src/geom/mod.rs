//! Small geometric types shared by every stage: axis-aligned boxes, rays and affine maps, and
//! the validated numbers scene descriptions are made of ([`values`]).

mod icosphere;
pub mod values;

pub use icosphere::icosphere;

use glam::{Affine3A, Vec3};

/// Largest magnitude of a coordinate the acceleration trees are built over. obvhs adds,
/// halves and multiplies box coordinates (centroids, extents, surface areas): an object
/// translated to 3·10³⁸ made a centroid infinite and the build panic, and the areas of boxes
/// wider than about 10¹⁹ overflow. SDF objects beyond it are tested by every ray instead of
/// sitting in the tree; meshes beyond it are refused at load.
pub const LARGEST_TREE_COORDINATE: f32 = 1e18;

/// An axis-aligned bounding box; components may be infinite for unbounded shapes (planes,
/// infinite repetition). An empty box has `min > max`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: Vec3,
    /// Upper corner.
    pub max: Vec3,
}

impl Aabb {
    /// The box containing nothing.
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };
    /// The box containing everything.
    pub const INFINITE: Aabb = Aabb {
        min: Vec3::splat(f32::NEG_INFINITY),
        max: Vec3::splat(f32::INFINITY),
    };

    /// A box from its corners.
    pub fn new(min: Vec3, max: Vec3) -> Self {
        Aabb { min, max }
    }

    /// The box [−h, h].
    pub fn symmetric(half_extents: Vec3) -> Self {
        Aabb::new(-half_extents, half_extents)
    }

    /// Whether every component of both corners is finite.
    pub fn is_finite(&self) -> bool {
        self.min.is_finite() && self.max.is_finite()
    }

    /// The largest magnitude of its corners' coordinates (NaN-free boxes).
    pub fn reach(&self) -> f32 {
        self.min.abs().max(self.max.abs()).max_element()
    }

    /// Whether the box contains no point.
    pub fn is_empty(&self) -> bool {
        self.min.cmpgt(self.max).any()
    }

    /// The smallest box containing both.
    pub fn union(&self, other: &Aabb) -> Aabb {
        Aabb::new(self.min.min(other.min), self.max.max(other.max))
    }

    /// The overlap of both boxes (possibly empty).
    pub fn intersection(&self, other: &Aabb) -> Aabb {
        Aabb::new(self.min.max(other.min), self.max.min(other.max))
    }

    /// The box grown by `r` on every side.
    pub fn expand(&self, r: f32) -> Aabb {
        Aabb::new(self.min - Vec3::splat(r), self.max + Vec3::splat(r))
    }

    /// Centre of a finite box.
    pub fn center(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }

    /// Length of the diagonal (infinite for unbounded boxes).
    pub fn diagonal(&self) -> f32 {
        (self.max - self.min).length()
    }

    /// The eight corners of a finite box.
    pub fn corners(&self) -> [Vec3; 8] {
        let (a, b) = (self.min, self.max);
        [
            Vec3::new(a.x, a.y, a.z),
            Vec3::new(b.x, a.y, a.z),
            Vec3::new(a.x, b.y, a.z),
            Vec3::new(b.x, b.y, a.z),
            Vec3::new(a.x, a.y, b.z),
            Vec3::new(b.x, a.y, b.z),
            Vec3::new(a.x, b.y, b.z),
            Vec3::new(b.x, b.y, b.z),
        ]
    }

    /// The bounds of this box after an affine map. An axis that is infinite (in either
    /// direction) stays infinite only in the output axes it maps onto, so a slab repeated
    /// along x and z and then translated keeps its finite y extent.
    pub fn transformed(&self, m: &Affine3A) -> Aabb {
        if self.is_empty() {
            return *self;
        }
        // Centre/half-extent form (Arvo, "Transforming axis-aligned bounding boxes", 1990),
        // with infinite axes given centre 0 and infinite half-extent.
        let finite = self.min.is_finite_mask() & self.max.is_finite_mask();
        let centre = Vec3::select(finite, self.center(), Vec3::ZERO);
        let half = Vec3::select(finite, 0.5 * (self.max - self.min), Vec3::INFINITY);
        let mut out_centre: Vec3 = m.translation.into();
        let mut out_half = Vec3::ZERO;
        for i in 0..3 {
            let col: Vec3 = m.matrix3.col(i).into();
            out_centre += col * centre[i];
            for j in 0..3 {
                if col[j] != 0.0 {
                    out_half[j] += col[j].abs() * half[i];
                }
            }
        }
        Aabb::new(out_centre - out_half, out_centre + out_half)
    }

    /// Signed distance from `p` to the box surface (negative inside): exact (Quilez `sdBox`).
    pub fn signed_distance(&self, p: Vec3) -> f32 {
        let q = (p - self.center()).abs() - 0.5 * (self.max - self.min);
        q.max(Vec3::ZERO).length() + q.max_element().min(0.0)
    }

    /// The parametric interval [t0, t1] in which the ray is inside the closed box, clipped to
    /// [tmin, tmax]; `None` when it misses. Slab method (Kay & Kajiya 1986). On an axis where
    /// 1/d is not finite (the ray is parallel to the slab) the axis is a containment test
    /// min ≤ o ≤ max — computing (min − o)·∞ there would give NaN when the origin lies on a
    /// slab plane, and NaN must not widen the interval. Infinite boxes work; empty boxes and
    /// NaN bounds miss. Inlined: an interval returned through memory is read back in a wider
    /// word than it was written in, a stall on every ray's walk set-up.
    #[inline]
    pub fn ray_interval(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<(f32, f32)> {
        self.ray_interval_from(ray.origin, Vec3::ONE / ray.direction, tmin, tmax)
    }

    /// [`Aabb::ray_interval`] of the ray from `origin` whose reciprocal direction is `inv`
    /// (computed once for many boxes).
    #[inline]
    pub fn ray_interval_from(
        &self,
        origin: Vec3,
        inv: Vec3,
        tmin: f32,
        tmax: f32,
    ) -> Option<(f32, f32)> {
        let (mut t_near, mut t_far) = (tmin, tmax);
        for axis in 0..3 {
            let (o, lo, hi) = (origin[axis], self.min[axis], self.max[axis]);
            let inv = inv[axis];
            if inv.is_finite() {
                let t_a = (lo - o) * inv;
                let t_b = (hi - o) * inv;
                let (n, f) = if inv < 0.0 { (t_b, t_a) } else { (t_a, t_b) };
                // written so that a NaN (from NaN input only) fails the test
                if !(n <= t_far && f >= t_near) {
                    return None;
                }
                t_near = t_near.max(n);
                t_far = t_far.min(f);
            } else if !(lo <= o && o <= hi) {
                return None;
            }
        }
        (t_near <= t_far).then_some((t_near, t_far))
    }
}

/// A ray origin + t·direction; `direction` is unit length everywhere in the tracer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Where the ray starts.
    pub origin: Vec3,
    /// Unit direction.
    pub direction: Vec3,
}

impl Ray {
    /// A ray with the direction normalised.
    pub fn new(origin: Vec3, direction: Vec3) -> Self {
        Ray {
            origin,
            direction: direction.normalize(),
        }
    }

    /// The point at parameter t.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + t * self.direction
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_interval_of_unit_box() {
        let b = Aabb::symmetric(Vec3::ONE);
        let r = Ray::new(Vec3::new(0.0, 0.0, -5.0), Vec3::Z);
        assert_eq!(b.ray_interval(&r, 0.0, 100.0), Some((4.0, 6.0)));
        let miss = Ray::new(Vec3::new(2.0, 0.0, -5.0), Vec3::Z);
        assert_eq!(b.ray_interval(&miss, 0.0, 100.0), None);
        let inside = Ray::new(Vec3::ZERO, Vec3::X);
        assert_eq!(b.ray_interval(&inside, 0.0, 100.0), Some((0.0, 1.0)));
    }

    #[test]
    fn transforms_keep_finite_axes_finite() {
        let slab = Aabb::new(
            Vec3::new(f32::NEG_INFINITY, -1.0, f32::NEG_INFINITY),
            Vec3::new(f32::INFINITY, 1.0, f32::INFINITY),
        );
        let moved = slab.transformed(&Affine3A::from_translation(Vec3::new(1.0, 2.0, 3.0)));
        assert_eq!((moved.min.y, moved.max.y), (1.0, 3.0));
        assert!(moved.min.x.is_infinite() && moved.max.z.is_infinite());
        let b = Aabb::symmetric(Vec3::new(1.0, 2.0, 3.0));
        let r = b.transformed(&Affine3A::from_rotation_y(std::f32::consts::FRAC_PI_2));
        assert!((r.max - Vec3::new(3.0, 2.0, 1.0)).length() < 1e-5);
    }

    #[test]
    fn rays_on_slab_planes_and_empty_boxes_miss_correctly() {
        // parallel to y, origin on the box's z plane but far away in x: a miss
        let flat = Aabb::new(Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, 1.0, 0.0));
        let r = Ray::new(Vec3::new(100.0, -5.0, 0.0), Vec3::Y);
        assert_eq!(flat.ray_interval(&r, 0.0, 15.0), None);
        assert_eq!(Aabb::EMPTY.ray_interval(&r, 0.0, 15.0), None);
    }

    #[test]
    fn infinite_box_contains_every_ray() {
        let r = Ray::new(Vec3::new(3.0, 1.0, 2.0), Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(
            Aabb::INFINITE.ray_interval(&r, 0.0, 50.0),
            Some((0.0, 50.0))
        );
    }
}
