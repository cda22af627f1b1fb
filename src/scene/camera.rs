//! Cameras: pinhole and orthographic, turning image-plane positions into primary rays.

use crate::geom::Ray;
use glam::Vec3;

/// A camera placed in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye (perspective) or image-plane centre (orthographic).
    pub position: Vec3,
    /// Unit viewing direction.
    pub forward: Vec3,
    /// Unit right vector.
    pub right: Vec3,
    /// Unit up vector (orthogonal to forward and right).
    pub up: Vec3,
    /// Projection.
    pub projection: Projection,
    /// The point it was aimed at (the viewer orbits about it).
    pub look_at: Vec3,
    /// The up direction it was placed with, before it was made orthogonal to `forward`.
    pub up_hint: Vec3,
}

/// How the image plane maps to rays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Projection {
    /// Pinhole with tan(fov_y / 2).
    Perspective {
        /// tan of half the vertical field of view.
        tan_half_fov: f32,
    },
    /// Parallel rays over a view of this height in world units.
    Orthographic {
        /// View height.
        height: f32,
    },
}

impl Projection {
    /// A pinhole whose vertical field of view is `fov_degrees`: the one conversion from the
    /// scene file's `fov`, so a camera the viewer prints reloads bit for bit.
    pub fn perspective_degrees(fov_degrees: f32) -> Projection {
        Projection::Perspective {
            tan_half_fov: (0.5 * fov_degrees.to_radians()).tan(),
        }
    }
}

impl Camera {
    /// A camera at `position` looking at `look_at`. Fails when the two coincide or `up` is
    /// parallel to the view direction.
    pub fn look_at(
        position: Vec3,
        look_at: Vec3,
        up: Vec3,
        projection: Projection,
    ) -> Result<Camera, String> {
        let mut forward = (look_at - position).normalize_or_zero();
        let scale = position.abs().max(look_at.abs()).max_element();
        if forward == Vec3::ZERO && scale.is_finite() && scale > 0.0 {
            // The difference or its square overflowed (points 10²⁰ apart): the same direction
            // from both points scaled down first.
            forward = (look_at / scale - position / scale).normalize_or_zero();
        }
        if forward == Vec3::ZERO {
            return Err("camera position and look_at are the same point".into());
        }
        let right = forward.cross(up);
        if right.length_squared() < 1e-10 {
            return Err("camera up is parallel to the viewing direction".into());
        }
        let right = right.normalize();
        Ok(Camera {
            position,
            forward,
            right,
            up: right.cross(forward),
            projection,
            look_at,
            up_hint: up,
        })
    }

    /// The ray through normalised image coordinates (u, v) ∈ [0, 1]², u to the right and v
    /// downwards (row order), for an image of the given aspect ratio (width / height).
    pub fn ray(&self, u: f32, v: f32, aspect: f32) -> Ray {
        let sx = (2.0 * u - 1.0) * aspect;
        let sy = 1.0 - 2.0 * v;
        match self.projection {
            Projection::Perspective { tan_half_fov } => Ray::new(
                self.position,
                self.forward + tan_half_fov * (sx * self.right + sy * self.up),
            ),
            Projection::Orthographic { height } => {
                let h = 0.5 * height;
                Ray::new(
                    self.position + h * (sx * self.right + sy * self.up),
                    self.forward,
                )
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_ray_looks_at_target() {
        let c = Camera::look_at(
            Vec3::new(0.0, 0.0, -5.0),
            Vec3::ZERO,
            Vec3::Y,
            Projection::Perspective { tan_half_fov: 0.5 },
        )
        .unwrap();
        let r = c.ray(0.5, 0.5, 1.5);
        assert!((r.direction - Vec3::Z).length() < 1e-6);
        // top edge of the image: 0.5 above the axis at unit distance
        let top = c.ray(0.5, 0.0, 1.0);
        assert!((top.direction.y / top.direction.z - 0.5).abs() < 1e-6);
        // right-handed: looking down +z with +y up, the image's right is −x (forward × up)
        let right = c.ray(1.0, 0.5, 1.0);
        assert!(right.direction.x < 0.0);
    }

    #[test]
    fn degenerate_cameras_are_refused() {
        let p = Projection::Orthographic { height: 2.0 };
        assert!(Camera::look_at(Vec3::ONE, Vec3::ONE, Vec3::Y, p).is_err());
        assert!(Camera::look_at(Vec3::ZERO, Vec3::Y, Vec3::Y, p).is_err());
    }
}
