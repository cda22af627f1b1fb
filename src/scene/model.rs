//! A mesh file rendered on its own: the scene `hytrace render model.glb` builds around it.

use super::camera::{Camera, Projection};
use super::file::{NormalMethod, ToneMap};
use super::mesh::{CameraProjection, LightKind, NamedCamera};
use super::{
    ImageSettings, Light, Scene, SceneError, SceneMeshes, ShadingSettings, Shadow, TracerSettings,
};
use crate::scene::material::MaterialParams;
use glam::{Affine3A, Vec3};
use std::path::Path;

/// Vertical field of view of the default camera, in degrees.
const DEFAULT_FOV: f32 = 40.0;

impl Scene {
    /// A scene holding only the mesh file at `path`: its lights (KHR_lights_punctual) or, when
    /// it has none, an ambient, a key and a fill light; the file camera named (or numbered)
    /// `camera`, or else a camera looking at the model's bounds from the front-right, above.
    /// Tracer offsets and distances scale with the model's size.
    pub fn from_model(path: &Path, camera: Option<&str>) -> Result<Scene, SceneError> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "model".into());
        let mut meshes = SceneMeshes::new(1);
        meshes
            .add_file(path, Affine3A::IDENTITY, None, &name)
            .map_err(SceneError::Mesh)?;
        let bounds = meshes.bounds();
        if bounds.is_empty() || !bounds.is_finite() {
            return Err(SceneError::File {
                file: path.to_path_buf(),
                message: "the file holds no triangles to render".into(),
            });
        }
        let centre = bounds.center();
        let radius = (0.5 * bounds.diagonal()).max(1e-6);
        let camera = match camera {
            Some(choice) => {
                file_camera(&meshes.cameras, choice).map_err(|message| SceneError::File {
                    file: path.to_path_buf(),
                    message,
                })?
            }
            None => {
                let dir = Vec3::new(0.55, 0.45, 1.0).normalize();
                let distance = 1.15 * radius / (0.5 * DEFAULT_FOV.to_radians()).sin();
                // (a model whose extent overflows 32-bit floats leaves no camera to frame it)
                Camera::look_at(
                    centre + dir * distance,
                    centre,
                    Vec3::Y,
                    Projection::perspective_degrees(DEFAULT_FOV),
                )
                .map_err(|e| SceneError::File {
                    file: path.to_path_buf(),
                    message: format!(
                        "no camera can frame the model, whose coordinates reach {:e}: {e}",
                        bounds.reach()
                    ),
                })?
            }
        };
        let mut lights: Vec<Light> = meshes
            .lights
            .iter()
            .map(|l| {
                // KHR_lights_punctual's units are photometric: I candela at distance d give
                // I/d² lux, a directional light gives its lux. One lux is the renderer's unit
                // of irradiance, so the file's lights keep their ratios; the exposure below
                // brings them to the display's range.
                let radiance = l.color * l.intensity;
                let range = l.range.unwrap_or(f32::INFINITY);
                match l.kind {
                    LightKind::Point { position } => Light::Point {
                        position,
                        radiance,
                        range,
                        shadow: Shadow::Hard,
                    },
                    LightKind::Spot {
                        position,
                        direction,
                        inner_cone_angle,
                        outer_cone_angle,
                    } => Light::Spot {
                        position,
                        direction,
                        radiance,
                        cos_inner: inner_cone_angle.cos(),
                        cos_outer: outer_cone_angle.cos(),
                        range,
                        shadow: Shadow::Hard,
                    },
                    LightKind::Directional { direction } => Light::Directional {
                        direction,
                        radiance,
                        shadow: Shadow::Hard,
                    },
                }
            })
            .collect();
        let exposure = metered_exposure(&lights, centre, radius);
        if lights.is_empty() {
            lights = vec![
                Light::Ambient {
                    radiance: Vec3::new(0.5, 0.55, 0.65) * 0.35,
                },
                Light::Directional {
                    direction: Vec3::new(-0.4, -1.0, -0.55).normalize(),
                    radiance: Vec3::new(1.0, 0.96, 0.9),
                    shadow: Shadow::Hard,
                },
                Light::Directional {
                    direction: Vec3::new(0.7, -0.3, 0.4).normalize(),
                    radiance: Vec3::splat(0.25),
                    shadow: Shadow::None,
                },
            ];
        }
        let mut materials = vec![MaterialParams::default_grey()];
        let mut material_names = vec!["(default)".to_string()];
        materials.extend(meshes.materials.iter().map(|m| m.params));
        material_names.extend(meshes.materials.iter().map(|m| m.name.clone()));
        Ok(Scene {
            source_name: path.display().to_string(),
            image: ImageSettings {
                width: 800,
                height: 600,
                samples: 1,
                background: Vec3::new(0.16, 0.18, 0.22),
                exposure,
                tonemap: ToneMap::Aces,
            },
            camera,
            lights,
            materials,
            material_names,
            objects: Vec::new(),
            tracer: TracerSettings {
                epsilon: 1e-5 * radius,
                epsilon_per_unit: 1e-4,
                max_distance: 100.0 * radius + (camera_distance(&camera, centre)),
                max_steps: 256,
                normals: NormalMethod::Central,
                shadows: true,
                bvh: crate::scene::file::BuildQuality::Medium,
                stepper: crate::scene::Stepper::Hart,
            },
            shading: ShadingSettings {
                ambient_occlusion: None,
                max_bounces: 4,
            },
            meshes,
        })
    }
}

/// The exposure, in stops, of a model rendered with its own lights: a camera meter's choice,
/// which makes the irradiance the lights bring to the centre of the model's bounds display as
/// 1 (a point or spot light counted at a distance of at least the bounds' radius, on its
/// cone's axis, so a light inside the model does not blind the meter). 0 when the file has no
/// lights (the renderer's own key and fill lights are made for exposure 0) or they bring
/// nothing; clamped to ±24 stops.
fn metered_exposure(lights: &[Light], centre: Vec3, radius: f32) -> f32 {
    let metered: f32 = lights
        .iter()
        .map(|l| match *l {
            Light::Point {
                position, radiance, ..
            }
            | Light::Spot {
                position, radiance, ..
            } => {
                let d = (position - centre).length().max(radius);
                radiance.max_element() / (d * d)
            }
            Light::Directional { radiance, .. } => radiance.max_element(),
            Light::Ambient { radiance } => radiance.max_element(),
        })
        .sum();
    if metered > 0.0 && metered.is_finite() {
        (-metered.log2()).clamp(-24.0, 24.0)
    } else {
        0.0
    }
}

fn camera_distance(camera: &Camera, centre: Vec3) -> f32 {
    (camera.position - centre).length()
}

/// The file camera named `choice`, or numbered `choice` (from 0).
fn file_camera(cameras: &[NamedCamera], choice: &str) -> Result<Camera, String> {
    let list = || {
        if cameras.is_empty() {
            "the file has no cameras".to_string()
        } else {
            let names: Vec<String> = cameras
                .iter()
                .enumerate()
                .map(|(i, c)| format!("{i}: \"{}\"", c.name))
                .collect();
            format!("the file's cameras are {}", names.join(", "))
        }
    };
    let found = cameras
        .iter()
        .find(|c| c.name == choice)
        .or_else(|| choice.parse::<usize>().ok().and_then(|i| cameras.get(i)))
        .ok_or_else(|| format!("--camera {choice}: no such camera ({})", list()))?;
    let projection = match found.projection {
        CameraProjection::Perspective { yfov_radians, .. } => Projection::Perspective {
            tan_half_fov: (0.5 * yfov_radians).tan(),
        },
        CameraProjection::Orthographic { ymag, .. } => {
            Projection::Orthographic { height: 2.0 * ymag }
        }
    };
    Camera::look_at(
        found.position,
        found.position + found.forward,
        found.up,
        projection,
    )
    .map_err(|e| format!("camera \"{}\": {e}", found.name))
}
