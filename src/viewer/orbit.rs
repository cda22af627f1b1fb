//! The viewer's camera: a turntable orbit about a pivot, pan, dolly zoom, fly steps and
//! framing, kept in the terms of the scene file so that the camera it prints reloads bit for bit.

use crate::geom::Aabb;
use crate::scene::Scene;
use crate::scene::camera::{Camera, Projection};
use glam::{Quat, Vec3};

/// How the image plane maps to rays, as the scene file writes it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Lens {
    /// Pinhole with this vertical field of view in degrees.
    Perspective {
        /// Vertical field of view, degrees.
        fov: f32,
    },
    /// Parallel rays over a view of this height in world units.
    Orthographic {
        /// View height.
        height: f32,
    },
}

impl Lens {
    /// The projection the scene loader makes of the same numbers.
    fn projection(self) -> Projection {
        match self {
            Lens::Perspective { fov } => Projection::perspective_degrees(fov),
            Lens::Orthographic { height } => Projection::Orthographic { height },
        }
    }
}

/// The field of view, in degrees, whose projection has this `tan_half_fov`: 2·atan(t) in
/// degrees does not round-trip (a scene's `fov: 47.1` came back as 47.099995, whose camera
/// differed from the scene's in 24 pixels), so the `f32`s next to it are tried for those
/// that [`Projection::perspective_degrees`] turns into the same bits; of those the one
/// written shortest (`60`, not the `60.000004` that gives the same camera), else 2·atan(t)
/// itself.
fn fov_of(tan_half_fov: f32) -> f32 {
    let first = 2.0 * tan_half_fov.atan().to_degrees();
    let same = |fov: f32| {
        matches!(Projection::perspective_degrees(fov),
            Projection::Perspective { tan_half_fov: t } if t == tan_half_fov)
    };
    (0..=64u32)
        .flat_map(|k| {
            let (up, down) = (first.to_bits() + k, first.to_bits().saturating_sub(k));
            [f32::from_bits(down), f32::from_bits(up)]
        })
        .filter(|&fov| fov.is_finite() && fov > 0.0 && same(fov))
        // (min_by_key keeps the first of equals: the nearest of the shortest)
        .min_by_key(|fov| format!("{fov:?}").len())
        .unwrap_or(first)
}

/// A camera placed by position, the point it looks at (the orbit pivot) and an up direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Eye (perspective) or image-plane centre (orthographic).
    pub position: Vec3,
    /// The point looked at; orbits turn about it.
    pub pivot: Vec3,
    /// The world's up direction: the turntable's axis.
    pub up: Vec3,
    /// Projection.
    pub lens: Lens,
}

/// Smallest angle, in radians, kept between the view direction and the up axis, so the
/// camera never looks straight along it (where `Camera::look_at` has no right vector).
const POLE_MARGIN: f32 = 0.02;
/// Radians of orbit per pixel of drag (a drag across 600 pixels turns about 3/4 of a turn).
const ORBIT_PER_PIXEL: f32 = 0.008;
/// Factor of the pivot distance per wheel notch.
const ZOOM_PER_NOTCH: f32 = 0.9;
/// Fraction of the pivot distance one fly key press moves.
const FLY_FRACTION: f32 = 0.05;

impl Pose {
    /// The pose of a scene's camera: its position, the point it was aimed at, its up hint.
    pub fn of_camera(camera: &Camera) -> Pose {
        let lens = match camera.projection {
            Projection::Perspective { tan_half_fov } => Lens::Perspective {
                fov: fov_of(tan_half_fov),
            },
            Projection::Orthographic { height } => Lens::Orthographic { height },
        };
        let mut pivot = camera.look_at;
        if (pivot - camera.position).length_squared() < 1e-12 {
            pivot = camera.position + camera.forward;
        }
        Pose {
            position: camera.position,
            pivot,
            up: camera.up_hint,
            lens,
        }
    }

    /// The camera the scene loader would build from [`Pose::to_ron`]'s text: the same
    /// constructor, the same normalisation of `up`, the same field-of-view conversion.
    pub fn camera(&self) -> Camera {
        let up = if self.up.is_finite() && self.up.length_squared() > 1e-12 {
            crate::geom::values::unit(self.up)
        } else {
            Vec3::Y
        };
        Camera::look_at(self.position, self.pivot, up, self.lens.projection()).unwrap_or_else(
            |_| {
                // a pose is kept away from the poles and off its pivot; should rounding put it
                // there anyway, look along -z rather than fail
                Camera::look_at(
                    self.position,
                    self.position - Vec3::Z,
                    Vec3::Y,
                    self.lens.projection(),
                )
                .expect("looking along -z with +y up is never degenerate")
            },
        )
    }

    /// The camera as a scene-file snippet to paste over the scene's `camera:` line. Numbers are
    /// written in Rust's shortest round-trip form, so the loader reads back the same bits.
    pub fn to_ron(&self) -> String {
        let v = |v: Vec3| format!("({:?}, {:?}, {:?})", v.x, v.y, v.z);
        match self.lens {
            Lens::Perspective { fov } => format!(
                "camera: Perspective(position: {}, look_at: {}, up: {}, fov: {:?}),",
                v(self.position),
                v(self.pivot),
                v(self.up),
                fov
            ),
            Lens::Orthographic { height } => format!(
                "camera: Orthographic(position: {}, look_at: {}, up: {}, height: {:?}),",
                v(self.position),
                v(self.pivot),
                v(self.up),
                height
            ),
        }
    }

    /// Distance from the eye to the pivot.
    pub fn distance(&self) -> f32 {
        (self.position - self.pivot).length()
    }

    /// Turns the eye about the pivot: `dx` pixels of drag about the up axis, `dy` about the
    /// camera's right axis, stopping short of looking along the up axis.
    pub fn orbit(&mut self, dx: f32, dy: f32) {
        let up = self.up.normalize_or(Vec3::Y);
        let offset = self.position - self.pivot;
        let yawed = Quat::from_axis_angle(up, -dx * ORBIT_PER_PIXEL) * offset;
        // the elevation of the eye above the turntable, kept inside (−π/2, π/2)
        let radius = yawed.length();
        if radius <= 0.0 {
            return;
        }
        let elevation = (yawed.dot(up) / radius).clamp(-1.0, 1.0).asin();
        let limit = std::f32::consts::FRAC_PI_2 - POLE_MARGIN;
        let wanted = (elevation + dy * ORBIT_PER_PIXEL).clamp(-limit, limit);
        let right = up.cross(yawed).normalize_or_zero();
        let turned = if right == Vec3::ZERO {
            yawed
        } else {
            Quat::from_axis_angle(right, elevation - wanted) * yawed
        };
        self.position = self.pivot + turned;
    }

    /// Slides eye and pivot in the image plane so the point under the cursor follows a drag of
    /// (`dx`, `dy`) pixels in a view `view_height` pixels tall.
    pub fn pan(&mut self, dx: f32, dy: f32, view_height: f32) {
        let camera = self.camera();
        let world_per_pixel = match self.lens {
            Lens::Perspective { fov } => {
                2.0 * self.distance() * (0.5 * fov.to_radians()).tan() / view_height.max(1.0)
            }
            Lens::Orthographic { height } => height / view_height.max(1.0),
        };
        let shift = world_per_pixel * (-dx * camera.right + dy * camera.up);
        self.position += shift;
        self.pivot += shift;
    }

    /// Dollies toward the pivot by `notches` wheel notches (negative: away); an orthographic
    /// view shrinks its height instead.
    pub fn zoom(&mut self, notches: f32) {
        let factor = ZOOM_PER_NOTCH.powf(notches.clamp(-50.0, 50.0));
        match &mut self.lens {
            Lens::Perspective { .. } => {
                let offset = (self.position - self.pivot) * factor;
                if offset.length() > 1e-4 && offset.length() < 1e7 {
                    self.position = self.pivot + offset;
                }
            }
            Lens::Orthographic { height } => {
                let h = *height * factor;
                if h > 1e-4 && h < 1e7 {
                    *height = h;
                }
            }
        }
    }

    /// Moves eye and pivot together by one fly step: `forward`, `right` and `up` are −1, 0 or
    /// 1 along the camera's axes (up is the world's up).
    pub fn fly(&mut self, forward: f32, right: f32, up: f32) {
        let camera = self.camera();
        let step = FLY_FRACTION * self.distance().max(1e-3);
        let shift = step
            * (forward * camera.forward
                + right * camera.right
                + up * self.up.normalize_or(Vec3::Y));
        self.position += shift;
        self.pivot += shift;
    }

    /// Looks at the centre of `bounds` from the current direction, from far enough that the
    /// bounding sphere fits the view.
    pub fn frame(&mut self, bounds: &Aabb, aspect: f32) {
        if bounds.is_empty() || !bounds.is_finite() {
            return;
        }
        let centre = bounds.center();
        let radius = (0.5 * bounds.diagonal()).max(1e-4);
        let direction = (self.position - self.pivot).normalize_or(Vec3::Z);
        match &mut self.lens {
            Lens::Perspective { fov } => {
                let half = 0.5 * fov.to_radians();
                // the narrower of the two half-angles decides
                let narrow = half.min((half.tan() * aspect.min(1.0)).atan());
                self.position = centre + direction * (1.1 * radius / narrow.sin());
            }
            Lens::Orthographic { height } => {
                *height = 2.2 * radius / aspect.min(1.0);
                self.position = centre + direction * (2.0 * radius);
            }
        }
        self.pivot = centre;
    }

    /// Aims at `point` from where the eye is (a click on a surface makes it the pivot).
    pub fn aim_at(&mut self, point: Vec3) {
        if (point - self.position).length_squared() > 1e-10 && point.is_finite() {
            self.pivot = point;
        }
    }
}

/// The finite part of a scene's extent: its meshes and every SDF object with finite bounds
/// (ground planes and infinite repetitions are left out), or `None` when there is none.
pub fn finite_bounds(scene: &Scene) -> Option<Aabb> {
    let b = scene
        .objects
        .iter()
        .map(|o| o.bounds())
        .filter(|b| b.is_finite() && !b.is_empty())
        .fold(scene.meshes.bounds(), |acc, b| acc.union(&b));
    (b.is_finite() && !b.is_empty()).then_some(b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn scene_with(camera_line: &str) -> Scene {
        let text = format!(
            "Scene({camera_line} objects: [(shape: Sphere(radius: 1))])",
            camera_line = camera_line
        );
        Scene::from_source(&text, Path::new("<test>")).unwrap()
    }

    #[test]
    fn printed_camera_reloads_bit_for_bit() {
        let scene = scene_with(
            "camera: Perspective(position: (0.3, 2.1, 6), look_at: (0, 0.8, 0.1), fov: 37),",
        );
        let mut pose = Pose::of_camera(&scene.camera);
        for step in 0..40 {
            pose.orbit(13.7 * step as f32, -3.1 * step as f32);
            pose.zoom(0.7);
            pose.pan(5.0, -2.0, 480.0);
            let reloaded = scene_with(&pose.to_ron()).camera;
            assert_eq!(
                reloaded,
                pose.camera(),
                "after step {step}: {}",
                pose.to_ron()
            );
        }
        let ortho = scene_with(
            "camera: Orthographic(position: (0, 0, 5), look_at: (0, 0, 0), up: (0, 0.3, 1), height: 3),",
        );
        let mut pose = Pose::of_camera(&ortho.camera);
        pose.orbit(100.0, 50.0);
        pose.zoom(2.0);
        assert_eq!(scene_with(&pose.to_ron()).camera, pose.camera());
    }

    #[test]
    fn the_scene_camera_is_the_starting_camera() {
        // bit for bit, so the first picture (and `R`'s) is `render`'s: fields of view whose
        // 2·atan(tan(fov/2)) does not round-trip, and tilted up vectors
        for fov in [40.0, 47.1, 30.0, 55.0, 60.0, 42.0, 1.5, 178.9] {
            for up in [
                "(0, 1, 0)",
                "(0.3, 1, 0)",
                "(0, 1, 0.5)",
                "(-0.2, 0.9, 0.35)",
            ] {
                let scene = scene_with(&format!(
                    "camera: Perspective(position: (1, 2, 6), look_at: (0, 0.5, 0), up: {up}, \
                     fov: {fov}),"
                ));
                let pose = Pose::of_camera(&scene.camera);
                assert_eq!(pose.camera(), scene.camera, "fov {fov}, up {up}");
                // and `C` prints the scene's own number (60, not the 60.000004 that gives
                // the same camera)
                assert!(
                    pose.to_ron().contains(&format!("fov: {:?})", fov as f32)),
                    "{}",
                    pose.to_ron()
                );
            }
        }
        let ortho = scene_with(
            "camera: Orthographic(position: (0, 0, 5), look_at: (0, 0, 0), up: (0, 0.3, 1), height: 3),",
        );
        assert_eq!(Pose::of_camera(&ortho.camera).camera(), ortho.camera);
    }

    #[test]
    fn orbit_keeps_the_pivot_distance_and_stops_at_the_poles() {
        let scene =
            scene_with("camera: Perspective(position: (0, 1, 5), look_at: (0, 0, 0), fov: 40),");
        let mut pose = Pose::of_camera(&scene.camera);
        let d = pose.distance();
        pose.orbit(250.0, 0.0);
        assert!((pose.distance() - d).abs() < 1e-4 * d);
        assert!(
            (pose.position.y - 1.0).abs() < 1e-4,
            "a sideways drag keeps the height"
        );
        assert!(pose.position.x.abs() > 1.0, "and moves the eye round");
        pose.orbit(0.0, 10_000.0);
        let elevation = ((pose.position - pose.pivot).normalize().dot(Vec3::Y)).asin();
        assert!(elevation < std::f32::consts::FRAC_PI_2 - 0.5 * POLE_MARGIN);
        assert!(elevation > 1.4);
        // the camera is still well defined at the pole
        let c = pose.camera();
        assert!(c.right.is_finite() && c.right.length() > 0.99);
    }

    #[test]
    fn pan_moves_eye_and_pivot_together_and_zoom_approaches_the_pivot() {
        let scene =
            scene_with("camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),");
        let mut pose = Pose::of_camera(&scene.camera);
        pose.pan(100.0, 0.0, 400.0);
        assert!(
            pose.pivot.x < -0.1,
            "dragging right moves the scene right: the eye goes left"
        );
        assert!((pose.position - pose.pivot - Vec3::new(0.0, 0.0, 5.0)).length() < 1e-5);
        pose.zoom(1.0);
        assert!((pose.distance() - 4.5).abs() < 1e-4);
        pose.zoom(-1.0);
        assert!((pose.distance() - 5.0).abs() < 1e-4);
    }

    #[test]
    fn frame_puts_the_bounds_in_view() {
        let scene =
            scene_with("camera: Perspective(position: (0, 0, 50), look_at: (3, 0, 0), fov: 40),");
        let mut pose = Pose::of_camera(&scene.camera);
        let bounds = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0));
        pose.frame(&bounds, 16.0 / 9.0);
        assert_eq!(pose.pivot, Vec3::ZERO);
        let camera = pose.camera();
        for corner in bounds.corners() {
            let v = corner - camera.position;
            let z = v.dot(camera.forward);
            let y = v.dot(camera.up) / z;
            let x = v.dot(camera.right) / z;
            let t = (20.0f32).to_radians().tan();
            assert!(
                y.abs() < t && x.abs() < t * 16.0 / 9.0,
                "corner {corner} outside the view"
            );
        }
        let near = (pose.distance() - 3.0f32.sqrt()) / pose.distance();
        assert!(near > 0.3, "not absurdly far: {}", pose.distance());
    }

    #[test]
    fn fly_moves_along_the_view() {
        let scene =
            scene_with("camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),");
        let mut pose = Pose::of_camera(&scene.camera);
        pose.fly(1.0, 0.0, 0.0);
        assert!(pose.position.z < 5.0 && pose.pivot.z < 0.0);
        pose.fly(0.0, 0.0, 1.0);
        assert!(pose.position.y > 0.0);
    }

    #[test]
    fn finite_bounds_leave_out_planes() {
        let scene = Scene::from_source(
            "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)), objects: [\
             (shape: Plane(normal: (0, 1, 0), offset: 0)), (shape: Sphere(radius: 1), translate: (2, 0, 0))])",
            Path::new("<test>"),
        )
        .unwrap();
        let b = finite_bounds(&scene).unwrap();
        assert!((b.center() - Vec3::new(2.0, 0.0, 0.0)).length() < 0.2);
    }
}
