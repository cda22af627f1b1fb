//! The viewer's state without a window: the camera under the user's hands, the switches, and
//! the refinement schedule that picks each frame's resolution and sample.

use super::input::{Button, Input, Key};
use super::orbit::{Pose, finite_bounds};
use crate::geom::Aabb;
use crate::render::view::View;
use crate::scene::file::Stepper;
use crate::scene::{AmbientOcclusion, Scene};
use std::time::{Duration, Instant};

/// The switches of the viewer that change what is rendered or how it is shown.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Switches {
    /// Which picture of the framebuffer is shown.
    pub view: View,
    /// The sphere tracer's step rule.
    pub stepper: Stepper,
    /// Shadows on or off.
    pub shadows: bool,
    /// Ambient occlusion on or off.
    pub ambient_occlusion: bool,
    /// Exposure in stops.
    pub exposure: f32,
}

impl Switches {
    /// The scene's own settings, shown as its file asks.
    pub fn of_scene(scene: &Scene) -> Switches {
        Switches {
            view: View::Shaded,
            stepper: scene.tracer.stepper,
            shadows: scene.tracer.shadows,
            ambient_occlusion: scene.shading.ambient_occlusion.is_some(),
            exposure: scene.image.exposure,
        }
    }

    /// Sets the tracing switches on `scene`. `file_ao` is the occlusion its file asked for;
    /// turning occlusion on in a scene that has none uses Quilez's five samples along the
    /// normal, spaced by 1 % of the scene's size.
    pub fn apply(&self, scene: &mut Scene, file_ao: Option<AmbientOcclusion>) {
        scene.tracer.stepper = self.stepper;
        scene.tracer.shadows = self.shadows;
        scene.shading.ambient_occlusion = if self.ambient_occlusion {
            Some(file_ao.unwrap_or_else(|| {
                let size = finite_bounds(scene).map_or(1.0, |b| b.diagonal());
                AmbientOcclusion {
                    strength: 1.0,
                    steps: 5,
                    step: (0.01 * size).clamp(1e-4, 1e3),
                }
            }))
        } else {
            None
        };
    }

    /// A short description for the heads-up line.
    pub fn describe(&self) -> String {
        format!(
            "{}, {}, shadows {}, AO {}, {:+.1} EV",
            view_name(self.view),
            self.stepper,
            on_off(self.shadows),
            on_off(self.ambient_occlusion),
            self.exposure
        )
    }
}

fn on_off(b: bool) -> &'static str {
    if b { "on" } else { "off" }
}

/// The view's name as `--view` spells it.
pub fn view_name(view: View) -> &'static str {
    match view {
        View::Shaded => "shaded",
        View::Normals => "normals",
        View::Depth => "depth",
        View::Steps => "steps",
        View::Gradient => "gradient",
    }
}

/// What an input asks of the viewer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Action {
    /// Nothing to do.
    Nothing,
    /// The camera moved: render again.
    Camera,
    /// A tracing switch changed: the scene's settings change, render again.
    Tracing,
    /// Only the way the image is shown changed (view, exposure): show it again.
    Display,
    /// Find the surface under the cursor (normalised image coordinates) and aim at it.
    Pick {
        /// Horizontal, 0 at the left edge, 1 at the right.
        u: f32,
        /// Vertical, 0 at the top, 1 at the bottom.
        v: f32,
    },
    /// Print the camera.
    PrintCamera,
    /// Write a screenshot.
    Screenshot,
    /// Print the key bindings.
    Help,
    /// Close the window.
    Quit,
}

/// A drag in progress.
#[derive(Debug, Clone, Copy)]
struct Drag {
    button: Button,
    pan: bool,
    last: (f32, f32),
    travelled: f32,
}

/// A press that moves less than this many pixels before release is a click.
const CLICK_SLOP: f32 = 3.0;

/// The camera and switches under the user's hands.
#[derive(Debug, Clone)]
pub struct Controls {
    /// The camera now.
    pub pose: Pose,
    /// The scene's camera (reset returns to it).
    pub home: Pose,
    /// The switches.
    pub switches: Switches,
    /// The scene's finite extent (for framing).
    pub bounds: Option<Aabb>,
    /// Window size in pixels.
    pub window: (u32, u32),
    cursor: (f32, f32),
    shift: bool,
    drag: Option<Drag>,
}

impl Controls {
    /// Controls starting at the scene's camera, in a window of `window` pixels.
    pub fn new(scene: &Scene, window: (u32, u32)) -> Controls {
        let pose = Pose::of_camera(&scene.camera);
        Controls {
            pose,
            home: pose,
            switches: Switches::of_scene(scene),
            bounds: finite_bounds(scene),
            window,
            cursor: (0.0, 0.0),
            shift: false,
            drag: None,
        }
    }

    /// A reloaded scene: the camera stays where the user put it unless the file's camera
    /// changed (then the new one is taken), the extent is the new scene's.
    pub fn reloaded(&mut self, scene: &Scene) {
        let home = Pose::of_camera(&scene.camera);
        if home != self.home {
            self.home = home;
            self.pose = home;
        }
        self.bounds = finite_bounds(scene);
    }

    /// Whether a button is held down.
    pub fn dragging(&self) -> bool {
        self.drag.is_some()
    }

    /// Handles one input event.
    pub fn handle(&mut self, input: Input) -> Action {
        match input {
            Input::Shift(down) => {
                self.shift = down;
                Action::Nothing
            }
            Input::Move { x, y } => {
                self.cursor = (x, y);
                let Some(drag) = &mut self.drag else {
                    return Action::Nothing;
                };
                let (dx, dy) = (x - drag.last.0, y - drag.last.1);
                drag.last = (x, y);
                drag.travelled += dx.abs() + dy.abs();
                if dx == 0.0 && dy == 0.0 {
                    return Action::Nothing;
                }
                if drag.pan {
                    self.pose.pan(dx, dy, self.window.1 as f32);
                } else {
                    self.pose.orbit(dx, dy);
                }
                Action::Camera
            }
            Input::Press(button) => {
                self.drag = Some(Drag {
                    button,
                    pan: button == Button::Middle || self.shift,
                    last: self.cursor,
                    travelled: 0.0,
                });
                Action::Nothing
            }
            Input::Release(button) => match self.drag.take() {
                Some(d) if d.button == button => {
                    if button == Button::Left && !d.pan && d.travelled < CLICK_SLOP {
                        let (w, h) = (self.window.0.max(1) as f32, self.window.1.max(1) as f32);
                        Action::Pick {
                            u: (self.cursor.0 / w).clamp(0.0, 1.0),
                            v: (self.cursor.1 / h).clamp(0.0, 1.0),
                        }
                    } else {
                        Action::Nothing
                    }
                }
                other => {
                    self.drag = other;
                    Action::Nothing
                }
            },
            Input::Scroll(notches) => {
                self.pose.zoom(notches);
                Action::Camera
            }
            Input::Key(key) => self.key(key),
        }
    }

    fn key(&mut self, key: Key) -> Action {
        let c = match key {
            Key::Escape => return Action::Quit,
            Key::F1 => return Action::Help,
            Key::Char(c) => c,
        };
        let fly = |pose: &mut Pose, f: f32, r: f32, u: f32| {
            pose.fly(f, r, u);
            Action::Camera
        };
        match c {
            'w' => fly(&mut self.pose, 1.0, 0.0, 0.0),
            's' => fly(&mut self.pose, -1.0, 0.0, 0.0),
            'a' => fly(&mut self.pose, 0.0, -1.0, 0.0),
            'd' => fly(&mut self.pose, 0.0, 1.0, 0.0),
            'q' => fly(&mut self.pose, 0.0, 0.0, -1.0),
            'e' => fly(&mut self.pose, 0.0, 0.0, 1.0),
            'f' => match self.bounds {
                Some(b) => {
                    let aspect = self.window.0.max(1) as f32 / self.window.1.max(1) as f32;
                    self.pose.frame(&b, aspect);
                    Action::Camera
                }
                None => Action::Nothing,
            },
            'r' => {
                self.pose = self.home;
                Action::Camera
            }
            'c' => Action::PrintCamera,
            'p' => Action::Screenshot,
            'v' => {
                self.switches.view = match self.switches.view {
                    View::Shaded => View::Normals,
                    View::Normals => View::Depth,
                    View::Depth => View::Steps,
                    View::Steps => View::Gradient,
                    View::Gradient => View::Shaded,
                };
                Action::Display
            }
            't' => {
                self.switches.stepper = match self.switches.stepper {
                    Stepper::Hart => Stepper::Relaxed(1.6),
                    Stepper::Relaxed(_) => Stepper::Adaptive,
                    Stepper::Adaptive => Stepper::Segment,
                    Stepper::Segment => Stepper::Hart,
                };
                Action::Tracing
            }
            'h' => {
                self.switches.shadows = !self.switches.shadows;
                Action::Tracing
            }
            'o' => {
                self.switches.ambient_occlusion = !self.switches.ambient_occlusion;
                Action::Tracing
            }
            '+' | '=' => {
                self.switches.exposure = (self.switches.exposure + 0.5).min(64.0);
                Action::Display
            }
            '-' | '_' => {
                self.switches.exposure = (self.switches.exposure - 0.5).max(-64.0);
                Action::Display
            }
            _ => Action::Nothing,
        }
    }
}

/// The frame the schedule asks for next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Frame {
    /// One sample per pixel at the pixel centres, at a reduced size, while the camera moves.
    Preview {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
    },
    /// Sample `sample` of the full-size image (stratified as `render` places them).
    Refine {
        /// Which sample, from 0.
        sample: u32,
    },
    /// Nothing: the image has all its samples, or the camera still moves and its last
    /// preview shows where it is.
    Idle,
}

/// How long the camera must rest before the full-size image starts.
pub const REST: Duration = Duration::from_millis(120);

/// The refinement schedule: previews at a size that holds the frame rate while the camera
/// moves, then the full image sample by sample when it rests.
#[derive(Debug, Clone)]
pub struct Schedule {
    /// Samples per pixel of the refined image.
    pub samples: u32,
    /// Time one preview frame may take.
    pub budget: Duration,
    /// The largest factor by which a preview is smaller than the window, per side.
    pub max_divisor: u32,
    /// Full-size samples done since the last change.
    pub refined: u32,
    last_change: Instant,
    preview_pending: bool,
    /// Seconds per preview pixel, smoothed over recent previews.
    cost_per_pixel: Option<f64>,
}

impl Schedule {
    /// A schedule for `samples` samples per pixel and previews of at most `budget` each.
    pub fn new(samples: u32, budget: Duration, now: Instant) -> Schedule {
        Schedule {
            samples: samples.max(1),
            budget,
            max_divisor: 8,
            refined: 0,
            last_change: now,
            preview_pending: false,
            cost_per_pixel: None,
        }
    }

    /// The image changed (camera, scene, switches): previews until the camera rests, then
    /// refinement from the first sample.
    pub fn changed(&mut self, now: Instant) {
        self.refined = 0;
        self.last_change = now;
        self.preview_pending = true;
    }

    /// When the last change to what is rendered happened.
    pub fn last_change(&self) -> Instant {
        self.last_change
    }

    /// Whether the full image has all its samples.
    pub fn converged(&self) -> bool {
        self.refined >= self.samples
    }

    /// The preview size for a window of `window` pixels: the most pixels the last previews'
    /// cost says fit in the budget.
    pub fn preview_size(&self, window: (u32, u32)) -> (u32, u32) {
        let (w, h) = (window.0.max(1), window.1.max(1));
        let pixels = w as f64 * h as f64;
        let divisor = match self.cost_per_pixel {
            // start small: the first preview measures the cost
            None => 4.0,
            Some(c) => {
                let fit = PREVIEW_SHARE * self.budget.as_secs_f64() / c.max(1e-12);
                (pixels / fit).sqrt().clamp(1.0, self.max_divisor as f64)
            }
        };
        (
            ((w as f64 / divisor).round() as u32).max(1),
            ((h as f64 / divisor).round() as u32).max(1),
        )
    }

    /// What to render next, `dragging` saying whether a button is held.
    pub fn next(&self, now: Instant, window: (u32, u32), dragging: bool) -> Frame {
        let resting = !dragging && now.duration_since(self.last_change) >= REST;
        if resting && !self.converged() {
            Frame::Refine {
                sample: self.refined,
            }
        } else if !resting && self.preview_pending {
            let (width, height) = self.preview_size(window);
            Frame::Preview { width, height }
        } else {
            Frame::Idle
        }
    }

    /// When the next frame becomes due without any input (the end of the rest).
    pub fn wake_at(&self) -> Option<Instant> {
        (!self.converged()).then_some(self.last_change + REST)
    }

    /// A preview of `pixels` pixels was sent.
    pub fn preview_started(&mut self) {
        self.preview_pending = false;
    }

    /// A preview of `pixels` pixels took `elapsed`.
    pub fn preview_done(&mut self, pixels: u32, elapsed: Duration) {
        let c = elapsed.as_secs_f64() / pixels.max(1) as f64;
        self.cost_per_pixel = Some(match self.cost_per_pixel {
            None => c,
            Some(old) => 0.5 * old + 0.5 * c,
        });
    }

    /// Full-size sample `sample` was added.
    pub fn refined_sample(&mut self, sample: u32) {
        if sample == self.refined {
            self.refined += 1;
        }
    }
}

/// The share of a frame's time a preview's render is sized to: the cost per pixel varies
/// from frame to frame as the view turns, and the rest absorbs that and the presentation,
/// so the frame rate holds rather than hovering just under it.
const PREVIEW_SHARE: f64 = 0.85;

/// What the viewer measures of its own frames, for the benchmark: previews while the camera
/// moves, and how long the image takes to reach all its samples once it rests.
#[derive(Debug, Clone, Default)]
pub struct FrameStats {
    /// Previews shown.
    pub previews: u32,
    /// When the first and the last of them arrived.
    pub first_preview: Option<Instant>,
    /// When the last preview arrived.
    pub last_preview: Option<Instant>,
    /// Pixels of all previews.
    pub preview_pixels: u64,
    /// Render time of all previews.
    pub preview_render: Duration,
    /// From the last change to the last refined sample, when the image converged.
    pub converged_after: Option<Duration>,
    /// Samples of the converged image.
    pub samples: u32,
}

impl FrameStats {
    /// A preview of `pixels` pixels that took `render` arrived at `now`.
    pub fn preview(&mut self, pixels: u64, render: Duration, now: Instant) {
        self.previews += 1;
        self.first_preview.get_or_insert(now);
        self.last_preview = Some(now);
        self.preview_pixels += pixels;
        self.preview_render += render;
        self.converged_after = None;
    }

    /// One line: frame rate while moving (previews per second between the first and the last
    /// preview), their mean size and render time, and the time to converge.
    pub fn describe(&self) -> String {
        let moving = match (self.first_preview, self.last_preview) {
            (Some(a), Some(b)) if self.previews > 1 => {
                let span = b.duration_since(a).as_secs_f64();
                let n = self.previews as f64;
                format!(
                    "moving: {} previews in {span:.2} s = {:.1} fps, {:.0} px each, {:.1} ms \
                     render each",
                    self.previews,
                    (n - 1.0) / span.max(1e-9),
                    self.preview_pixels as f64 / n,
                    self.preview_render.as_secs_f64() * 1e3 / n
                )
            }
            _ => format!("moving: {} previews", self.previews),
        };
        let converge = match self.converged_after {
            Some(d) => format!(
                "converged to {} spp {:.2} s after the last change",
                self.samples,
                d.as_secs_f64()
            ),
            None => "not converged".into(),
        };
        format!("stats: {moving}; {converge}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn scene() -> Scene {
        Scene::from_source(
            "Scene(camera: Perspective(position: (0, 1, 5), look_at: (0, 0, 0), fov: 40), \
             objects: [(shape: Sphere(radius: 1))])",
            Path::new("<test>"),
        )
        .unwrap()
    }

    #[test]
    fn a_drag_orbits_and_a_click_picks() {
        let mut c = Controls::new(&scene(), (400, 300));
        c.handle(Input::Move { x: 100.0, y: 100.0 });
        assert_eq!(c.handle(Input::Press(Button::Left)), Action::Nothing);
        assert_eq!(c.handle(Input::Move { x: 150.0, y: 100.0 }), Action::Camera);
        assert_ne!(c.pose, c.home);
        assert_eq!(c.handle(Input::Release(Button::Left)), Action::Nothing);
        c.handle(Input::Move { x: 200.0, y: 150.0 });
        c.handle(Input::Press(Button::Left));
        assert_eq!(
            c.handle(Input::Release(Button::Left)),
            Action::Pick { u: 0.5, v: 0.5 }
        );
        assert_eq!(c.handle(Input::Key(Key::Char('r'))), Action::Camera);
        assert_eq!(c.pose, c.home);
    }

    #[test]
    fn shift_drag_and_middle_drag_pan() {
        let mut c = Controls::new(&scene(), (400, 300));
        let distance = c.pose.distance();
        c.handle(Input::Shift(true));
        c.handle(Input::Press(Button::Left));
        c.handle(Input::Move { x: 40.0, y: 0.0 });
        c.handle(Input::Release(Button::Left));
        c.handle(Input::Shift(false));
        assert!((c.pose.distance() - distance).abs() < 1e-4);
        assert!(c.pose.pivot.x < 0.0);
        let before = c.pose;
        c.handle(Input::Press(Button::Middle));
        c.handle(Input::Move { x: 40.0, y: 30.0 });
        assert!((c.pose.pivot - before.pivot).length() > 0.01);
    }

    #[test]
    fn keys_cycle_views_and_switches() {
        let mut c = Controls::new(&scene(), (400, 300));
        let seen: Vec<View> = (0..5)
            .map(|_| {
                assert_eq!(c.handle(Input::Key(Key::Char('v'))), Action::Display);
                c.switches.view
            })
            .collect();
        assert_eq!(
            seen,
            [
                View::Normals,
                View::Depth,
                View::Steps,
                View::Gradient,
                View::Shaded
            ]
        );
        assert_eq!(c.handle(Input::Key(Key::Char('h'))), Action::Tracing);
        assert!(!c.switches.shadows);
        assert_eq!(c.handle(Input::Key(Key::Char('t'))), Action::Tracing);
        assert_eq!(c.switches.stepper, Stepper::Relaxed(1.6));
        c.handle(Input::Key(Key::Char('+')));
        assert_eq!(c.switches.exposure, 0.5);
        let mut s = scene();
        c.handle(Input::Key(Key::Char('o')));
        c.switches.apply(&mut s, None);
        assert!(s.shading.ambient_occlusion.is_some() && !s.tracer.shadows);
        assert_eq!(c.handle(Input::Key(Key::Escape)), Action::Quit);
    }

    #[test]
    fn the_schedule_previews_while_moving_then_refines_every_sample() {
        let t0 = Instant::now();
        let mut s = Schedule::new(3, Duration::from_millis(40), t0);
        s.changed(t0);
        let Frame::Preview { width, height } = s.next(t0, (800, 600), true) else {
            panic!("a moving camera gets a preview")
        };
        assert!(width < 800 && height < 600);
        s.preview_started();
        assert_eq!(s.next(t0, (800, 600), true), Frame::Idle);
        // a cheap preview: the next one may be larger, never larger than the window
        s.preview_done(width * height, Duration::from_millis(1));
        assert_eq!(s.preview_size((800, 600)), (800, 600));
        // an expensive one: smaller, at most max_divisor smaller
        s.preview_done(width * height, Duration::from_secs(10));
        assert_eq!(s.preview_size((800, 600)), (100, 75));
        let rest = t0 + REST;
        for k in 0..3 {
            assert_eq!(s.next(rest, (800, 600), false), Frame::Refine { sample: k });
            s.refined_sample(k);
        }
        assert!(s.converged());
        assert_eq!(s.next(rest, (800, 600), false), Frame::Idle);
        s.changed(rest);
        assert!(!s.converged());
    }

    #[test]
    fn a_preview_is_sized_to_its_share_of_the_frame() {
        let t0 = Instant::now();
        let mut s = Schedule::new(1, Duration::from_millis(50), t0);
        // 1 µs per pixel: 42,500 pixels fit in 85 % of 50 ms
        s.preview_done(10_000, Duration::from_millis(10));
        let (w, h) = s.preview_size((800, 600));
        let fit = PREVIEW_SHARE * 0.05 / 1e-6;
        assert!(
            ((w * h) as f64 - fit).abs() / fit < 0.02,
            "{w}×{h} for {fit} pixels"
        );
        assert!(
            (w as f64 / h as f64 - 4.0 / 3.0).abs() < 0.02,
            "the window's aspect"
        );
    }
}
