//! The viewer's window: winit events in, the render thread's frames out through wgpu, with the
//! heads-up line, screenshots, scripts and hot reload.

use super::input::{Button, Input, KEY_HELP, Key};
use super::present::Presenter;
use super::script::Step;
use super::session::{Action, Controls, Frame, FrameStats, Schedule, Switches};
use super::watch::FileWatch;
use super::worker::{DeviceSums, Job, Report, Worker};
use crate::gpu::display::{HeadsUp, Shown};
use crate::render::exr::Aov;
use crate::render::output::ToneMapping;
use crate::render::view::{View, picture};
use crate::render::write::write_image;
use crate::render::{Framebuffer, RenderOptions, draw};
use crate::scene::Scene;
use crate::scene::file::ToneMap;
use image::{Rgb, RgbImage, RgbaImage};
use std::collections::VecDeque;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop, EventLoopProxy};
use winit::keyboard::{Key as WinitKey, NamedKey};
use winit::window::{Window, WindowId};

/// Loads the scene (again, on every reload).
pub type Loader = Arc<dyn Fn() -> anyhow::Result<Scene> + Send + Sync>;

/// How the viewer is set up (from the command line).
pub struct ViewerConfig {
    /// What the window's title calls the scene.
    pub title: String,
    /// Loads the scene; called again after every change of a watched file.
    pub load: Loader,
    /// The scene file itself, watched for changes (None for the built-in showcase).
    pub scene_file: Option<PathBuf>,
    /// How the scene file's mesh paths resolve, as `load` resolves them (for the mesh files
    /// a scene that fails to load names, which are watched too).
    pub load_options: crate::scene::LoadOptions,
    /// Window size in pixels (None: the scene's image size).
    pub size: Option<(u32, u32)>,
    /// Samples per pixel of the refined image (None: the scene's).
    pub samples: Option<u32>,
    /// Exposure in stops (None: the scene's).
    pub exposure: Option<f32>,
    /// Tone-mapping operator (None: the scene's).
    pub tonemap: Option<ToneMap>,
    /// EXR channels written beside each PNG screenshot.
    pub aov: Vec<Aov>,
    /// Render threads (None: all cores).
    pub threads: Option<usize>,
    /// Longest time a preview frame may take.
    pub frame_budget: Duration,
    /// Scripted steps, run from the first frame on.
    pub script: Vec<Step>,
    /// Close after this many frames.
    pub frames: Option<u64>,
    /// Where `P` writes screenshots (numbered files).
    pub screenshot_dir: PathBuf,
    /// Render the frames on the GPU that presents the window (the CPU renders them
    /// otherwise).
    pub render_on_gpu: bool,
}

/// What other threads tell the window.
enum Wake {
    Worker(Report),
    FilesChanged,
    /// A load finished: the number of the reload that started it, and its scene or error.
    Loaded(u64, Result<Box<Scene>, String>),
}

/// Fails with one line when the environment names no display to open a window on (X11's
/// DISPLAY, Wayland's WAYLAND_DISPLAY or WAYLAND_SOCKET), before anything else is set up;
/// winit's own message for this names its source file.
pub fn check_display() -> anyhow::Result<()> {
    let named = |v: &str| std::env::var_os(v).is_some_and(|d| !d.is_empty());
    if cfg!(target_os = "linux")
        && !["DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"]
            .iter()
            .any(|v| named(v))
    {
        anyhow::bail!(
            "cannot open a window: no display (neither DISPLAY nor WAYLAND_DISPLAY is set); \
             `hytrace render` writes images without one"
        );
    }
    Ok(())
}

/// Opens the window and runs until it closes. Fails with one line when there is no display
/// or no adapter to present with.
pub fn run(config: ViewerConfig) -> anyhow::Result<()> {
    if config.scene_file.is_none() && config.script.contains(&Step::WaitReload) {
        // it would wait forever
        anyhow::bail!(
            "the script waits for a reload, but the built-in showcase has no file to watch"
        );
    }
    let scene = (config.load)()?;
    let event_loop = EventLoop::<Wake>::with_user_event().build().map_err(|e| {
        anyhow::anyhow!(
            "cannot open a window: {e} (no display: is DISPLAY or WAYLAND_DISPLAY set?)"
        )
    })?;
    let proxy = event_loop.create_proxy();
    let mut app = Viewer::new(config, scene, proxy)?;
    event_loop.run_app(&mut app)?;
    if let Some(e) = app.fatal.take() {
        return Err(e);
    }
    // screenshots asked for but never written: the window closed first (`--frames`, or a
    // quit before the image had all its samples); a script's (and `--screenshot`'s) fail
    for path in &app.screenshots {
        eprintln!(
            "screenshot {} not written: the window closed before the image had all its samples",
            path.display()
        );
    }
    let unwritten = (app.script.iter())
        .flat_map(|run| &run.steps)
        .find_map(|step| match step {
            Step::Screenshot(path) => Some(path),
            _ => None,
        });
    match unwritten {
        Some(path) => Err(anyhow::anyhow!(
            "screenshot {} not written: the window closed before the script reached it \
             (after the frames --frames allows, or at a quit)",
            path.display()
        )),
        None => Ok(()),
    }
}

/// The frame the render thread is working on.
#[derive(Debug, Clone, Copy)]
struct InFlight {
    generation: u64,
    frame: Frame,
}

/// A frame as the render thread delivered it.
struct ShownFrame {
    /// On the host (every CPU frame; GPU frames read back).
    image: Option<Box<Framebuffer>>,
    /// A GPU frame's sums on the presenting device.
    on_device: Option<DeviceSums>,
}

/// The window's picture of the last frame.
struct Composed {
    /// The host's pixels of the picture (width, height, RGBA), or None to show the GPU's sums.
    pixels: Option<(u32, u32, Vec<u8>)>,
    /// The heads-up band: the window's width, the text over transparent pixels.
    heads_up: RgbaImage,
}

/// The script's progress.
struct ScriptRun {
    steps: VecDeque<Step>,
    resume_at: Instant,
    /// Reloads seen when a `wait-reload` started.
    reloads_at_wait: Option<u64>,
}

/// The viewer's state on the window's thread.
struct Viewer {
    config: ViewerConfig,
    proxy: EventLoopProxy<Wake>,
    window: Option<Arc<Window>>,
    presenter: Option<Presenter>,
    worker: Worker,
    controls: Controls,
    schedule: Schedule,
    /// Grows with every change to what is rendered; frames of older generations are stale.
    generation: u64,
    in_flight: Option<InFlight>,
    ready: bool,
    /// The last frame and whether it is the refined one of the current generation.
    shown: Option<(ShownFrame, Frame)>,
    /// What the window shows of it: the picture on the host (its view, tone-mapped, 8-bit
    /// RGBA) unless the GPU's sums are shown where they are, and the heads-up band.
    composed: Option<Composed>,
    tone_operator: ToneMap,
    max_steps: u32,
    backend: String,
    last_frame_ms: f64,
    frame_times: VecDeque<Instant>,
    frames_shown: u64,
    error: Option<String>,
    /// Why the GPU gave up on the scene or a frame (the CPU renders instead).
    gpu_fault: Option<String>,
    /// Frame statistics since the last script `stats`.
    stats: FrameStats,
    reloads: u64,
    /// Loads started by a change of a watched file; only the newest one's result is applied.
    reloads_started: u64,
    reload_at: Option<Instant>,
    watch: Option<FileWatch>,
    /// The files of the last scene that loaded (the scene file and its meshes).
    good_files: Vec<PathBuf>,
    screenshots: Vec<PathBuf>,
    next_screenshot: u32,
    script: Option<ScriptRun>,
    fatal: Option<anyhow::Error>,
    quit: bool,
}

impl Viewer {
    fn new(
        config: ViewerConfig,
        scene: Scene,
        proxy: EventLoopProxy<Wake>,
    ) -> anyhow::Result<Self> {
        let size = config
            .size
            .unwrap_or((scene.image.width, scene.image.height));
        let mut controls = Controls::new(&scene, size);
        if let Some(e) = config.exposure {
            controls.switches.exposure = e;
        }
        let now = Instant::now();
        let mut schedule = Schedule::new(
            config.samples.unwrap_or(scene.image.samples),
            config.frame_budget,
            now,
        );
        schedule.changed(now);
        let tone_operator = config.tonemap.unwrap_or(scene.image.tonemap);
        let max_steps = scene.tracer.max_steps;
        let files = watched_files(config.scene_file.as_deref(), &scene);
        let worker_proxy = proxy.clone();
        // on the GPU, the render thread gets the presenting device once the window exists
        let worker = Worker::start(scene, controls.switches, config.threads, None, move |r| {
            let _ = worker_proxy.send_event(Wake::Worker(r));
        })?;
        // frames of generation 1 are the ones wanted first
        worker.want(1);
        let watch = watch(&files, &proxy)?;
        let script = (!config.script.is_empty()).then(|| ScriptRun {
            steps: config.script.iter().cloned().collect(),
            resume_at: now,
            reloads_at_wait: None,
        });
        Ok(Viewer {
            config,
            proxy,
            window: None,
            presenter: None,
            worker,
            controls,
            schedule,
            generation: 1,
            in_flight: None,
            ready: false,
            shown: None,
            composed: None,
            tone_operator,
            max_steps,
            backend: "CPU".into(),
            last_frame_ms: 0.0,
            frame_times: VecDeque::new(),
            frames_shown: 0,
            error: None,
            gpu_fault: None,
            stats: FrameStats::default(),
            reloads: 0,
            reloads_started: 0,
            reload_at: None,
            watch,
            good_files: files,
            screenshots: Vec::new(),
            next_screenshot: 1,
            script,
            fatal: None,
            quit: false,
        })
    }

    fn fail(&mut self, event_loop: &ActiveEventLoop, error: anyhow::Error) {
        if self.fatal.is_none() {
            self.fatal = Some(error);
        }
        event_loop.exit();
    }

    /// Something about the image changed: newer frames are wanted, refinement starts over.
    ///
    /// A preview in flight is left to finish and is shown (it is at most one frame behind
    /// the camera): abandoning it at every mouse move would starve a drag of frames whenever
    /// a preview takes longer than the time between two moves. Refinement passes, which take
    /// the full image's time, are abandoned at once.
    fn changed(&mut self) {
        self.generation += 1;
        if !self
            .in_flight
            .is_some_and(|f| matches!(f.frame, Frame::Preview { .. }))
        {
            self.worker.want(self.generation);
        }
        self.schedule.changed(Instant::now());
    }

    fn act(&mut self, action: Action) {
        match action {
            Action::Nothing => {}
            Action::Camera => self.changed(),
            Action::Tracing => {
                self.worker.send(Job::Switches(self.controls.switches));
                self.ready = false;
                self.changed();
            }
            Action::Display => {
                // a debug view of a GPU frame needs the frame on the host: render it again
                let view = self.controls.switches.view;
                if view != View::Shaded
                    && self.shown.as_ref().is_some_and(|(f, _)| f.image.is_none())
                {
                    self.changed();
                }
                self.compose();
            }
            Action::Pick { u, v } => {
                let (w, h) = self.controls.window;
                self.worker.send(Job::Pick {
                    camera: self.controls.pose.camera(),
                    u,
                    v,
                    aspect: w.max(1) as f32 / h.max(1) as f32,
                });
            }
            Action::PrintCamera => {
                let mut out = std::io::stdout().lock();
                let _ = writeln!(out, "{}", self.controls.pose.to_ron());
                let _ = out.flush();
            }
            Action::Screenshot => {
                let path = loop {
                    let p = self
                        .config
                        .screenshot_dir
                        .join(format!("hytrace-view-{:03}.png", self.next_screenshot));
                    self.next_screenshot += 1;
                    if !p.exists() {
                        break p;
                    }
                };
                eprintln!(
                    "screenshot: {} (when the image has all its samples)",
                    path.display()
                );
                self.screenshots.push(path);
                // a refined image already on screen is written now, otherwise on arrival
                self.flush_screenshots();
            }
            Action::Help => {
                eprintln!("hytrace view keys:");
                for (k, what) in KEY_HELP {
                    eprintln!("  {k:<32} {what}");
                }
            }
            Action::Quit => self.quit = true,
        }
    }

    fn input(&mut self, input: Input) {
        let action = self.controls.handle(input);
        self.act(action);
    }

    /// The refined image of the current camera, if it has all its samples.
    fn refined(&self) -> Option<&Framebuffer> {
        if !self.schedule.converged() || self.in_flight.is_some() {
            return None;
        }
        match &self.shown {
            Some((f, Frame::Refine { .. })) => f.image.as_deref(),
            _ => None,
        }
    }

    fn tone(&self) -> ToneMapping {
        ToneMapping {
            exposure: self.controls.switches.exposure,
            operator: self.tone_operator,
        }
    }

    /// Writes a screenshot as `hytrace render` writes the same camera, size and samples:
    /// the picture of the current view, and an EXR beside it when AOVs were asked for.
    fn write_screenshot(&self, path: &Path, fb: &Framebuffer) -> Result<(), String> {
        let view = self.controls.switches.view;
        write_image(
            fb,
            path,
            view,
            self.tone(),
            self.max_steps,
            &self.config.aov,
        )
        .map_err(|e| format!("{e:#}"))?;
        let is_exr = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("exr"));
        if !self.config.aov.is_empty() && !is_exr {
            let exr = path.with_extension("exr");
            write_image(
                fb,
                &exr,
                view,
                self.tone(),
                self.max_steps,
                &self.config.aov,
            )
            .map_err(|e| format!("{e:#}"))?;
        }
        Ok(())
    }

    /// Writes the screenshots waiting for the refined image.
    fn flush_screenshots(&mut self) {
        if self.screenshots.is_empty() {
            return;
        }
        let Some(fb) = self.refined().cloned() else {
            return;
        };
        for path in std::mem::take(&mut self.screenshots) {
            match self.write_screenshot(&path, &fb) {
                Ok(()) => eprintln!("wrote {}", path.display()),
                Err(e) => eprintln!("error: {e}"),
            }
        }
    }

    /// Sends the next frame the schedule wants, if the render thread is free.
    fn schedule_frame(&mut self) {
        if self.in_flight.is_some() || !self.ready {
            return;
        }
        let window = self.controls.window;
        let frame = self
            .schedule
            .next(Instant::now(), window, self.controls.dragging());
        let options = match frame {
            Frame::Idle => return,
            Frame::Preview { width, height } => {
                self.schedule.preview_started();
                RenderOptions::single_sample(width, height)
            }
            Frame::Refine { .. } => RenderOptions {
                samples: self.schedule.samples,
                ..RenderOptions::single_sample(window.0, window.1)
            },
        };
        let sample = match frame {
            Frame::Refine { sample } => sample,
            _ => 0,
        };
        self.worker.want(self.generation);
        self.worker.send(Job::Frame {
            generation: self.generation,
            camera: self.controls.pose.camera(),
            options: RenderOptions {
                threads: self.config.threads,
                ..options
            },
            sample,
            read_back: self.controls.switches.view != View::Shaded,
        });
        self.in_flight = Some(InFlight {
            generation: self.generation,
            frame,
        });
    }

    fn report(&mut self, report: Report) {
        match report {
            Report::Ready { build, backend } => {
                self.ready = true;
                self.backend = backend;
                if build > Duration::from_millis(200) {
                    eprintln!(
                        "acceleration structures built in {:.2} s",
                        build.as_secs_f64()
                    );
                }
            }
            Report::Abandoned => self.in_flight = None,
            Report::Failed(e) => {
                eprintln!("error: {e}");
                self.gpu_fault = Some(e);
                self.compose();
            }
            Report::Picked(point) => {
                if let Some(p) = point {
                    self.controls.pose.aim_at(p);
                    self.changed();
                }
            }
            Report::Frame {
                generation,
                sample,
                image,
                on_device,
                elapsed,
            } => {
                let Some(done) = self.in_flight.take() else {
                    return;
                };
                let stale = generation != self.generation;
                let preview = matches!(done.frame, Frame::Preview { .. });
                if done.generation != generation || (stale && !preview) {
                    return;
                }
                match done.frame {
                    Frame::Preview { width, height } => {
                        self.schedule.preview_done(width * height, elapsed);
                        self.stats
                            .preview(width as u64 * height as u64, elapsed, Instant::now());
                    }
                    Frame::Refine { .. } => {
                        self.schedule.refined_sample(sample);
                        if self.schedule.converged() {
                            self.stats.converged_after =
                                Some(self.schedule.last_change().elapsed());
                            self.stats.samples = self.schedule.samples;
                        }
                    }
                    Frame::Idle => {}
                }
                self.last_frame_ms = elapsed.as_secs_f64() * 1e3;
                self.shown = Some((ShownFrame { image, on_device }, done.frame));
                // the render thread starts the next frame while this one is composed and
                // presented
                self.schedule_frame();
                self.frames_shown += 1;
                let now = Instant::now();
                self.frame_times.push_back(now);
                while self
                    .frame_times
                    .front()
                    .is_some_and(|t| now.duration_since(*t) > Duration::from_secs(1))
                {
                    self.frame_times.pop_front();
                }
                self.compose();
                self.flush_screenshots();
            }
        }
    }

    /// The heads-up line.
    fn heads_up(&self) -> String {
        let (w, h) = self.controls.window;
        let progress = match self.shown.as_ref().map(|s| s.1) {
            Some(Frame::Preview { width, height }) => format!("preview {width}x{height}"),
            Some(Frame::Refine { sample }) => {
                format!("{}/{} spp {w}x{h}", sample + 1, self.schedule.samples)
            }
            _ => "rendering".into(),
        };
        let adapter = self
            .presenter
            .as_ref()
            .map(|p| p.adapter().name.clone())
            .unwrap_or_default();
        format!(
            "{progress} | {:.0} ms/frame | {} fps | {} | present: {adapter} | {}",
            self.last_frame_ms,
            self.frame_times.len(),
            self.backend,
            self.controls.switches.describe()
        )
    }

    /// Makes the window's picture of the last frame and asks for it to be drawn.
    fn compose(&mut self) {
        let Some((frame, _)) = &self.shown else {
            return;
        };
        let (w, _) = self.controls.window;
        let view = self.controls.switches.view;
        // the shaded view of a GPU frame is tone-mapped where the render kernel left it
        let pixels = match (&frame.image, &frame.on_device) {
            (_, Some(_)) if view == View::Shaded => None,
            (Some(fb), _) => {
                let img = picture(fb, view, self.tone(), self.max_steps);
                Some((img.width(), img.height(), rgb_to_rgba(&img)))
            }
            // a GPU frame not read back, its debug view on the way: shaded meanwhile
            (None, _) => None,
        };
        let columns = (w / 8).max(8) as usize - 1;
        let mut lines: Vec<(String, [u8; 3])> = wrap(&self.heads_up(), columns)
            .into_iter()
            .map(|l| (l, [235, 235, 235]))
            .collect();
        if let Some(e) = &self.error {
            lines.push((
                "the scene did not reload; still showing the last good one:".into(),
                [255, 120, 100],
            ));
            for part in wrap(e, columns) {
                lines.push((part, [255, 120, 100]));
            }
        }
        if let Some(e) = &self.gpu_fault {
            for part in wrap(e, columns) {
                lines.push((part, [255, 200, 90]));
            }
        }
        let band = lines.len() as u32 * draw::LINE + 4;
        // the text on black, then black made transparent (no text colour is black)
        let mut text = RgbImage::new(w, band);
        for (i, (line, colour)) in lines.iter().enumerate() {
            let line: String = line
                .chars()
                .map(|c| if c.is_ascii() { c } else { '?' })
                .collect();
            draw::text(&mut text, 4, 2 + i as u32 * draw::LINE, &line, *colour);
        }
        let heads_up = RgbaImage::from_fn(w, band, |x, y| {
            let Rgb([r, g, b]) = *text.get_pixel(x, y);
            image::Rgba([r, g, b, if r | g | b == 0 { 0 } else { 255 }])
        });
        self.composed = Some(Composed { pixels, heads_up });
        if let Some(w) = &self.window {
            w.request_redraw();
        }
    }

    fn present(&mut self, event_loop: &ActiveEventLoop) {
        let tone = self.tone();
        let Some(presenter) = self.presenter.as_mut() else {
            return;
        };
        // (fields borrowed apart: the presenter mutably, the frame and picture shared)
        let Some((shown, composed)) = shown_picture(&self.composed, &self.shown, tone) else {
            return;
        };
        let heads_up = HeadsUp {
            text: &composed.heads_up,
        };
        if let Err(e) = presenter.present(&shown, &heads_up) {
            self.fail(event_loop, anyhow::anyhow!("cannot present the frame: {e}"));
        }
    }

    /// Starts loading the scene again on a thread of its own.
    fn reload(&mut self) {
        let load = self.config.load.clone();
        let proxy = self.proxy.clone();
        self.reloads_started += 1;
        let number = self.reloads_started;
        std::thread::spawn(move || {
            let result = load().map(Box::new).map_err(|e| format!("{e:#}"));
            let _ = proxy.send_event(Wake::Loaded(number, result));
        });
    }

    fn loaded(&mut self, result: Result<Box<Scene>, String>) {
        self.reloads += 1;
        match result {
            Ok(scene) => {
                if self.error.take().is_some() {
                    eprintln!("reloaded: the scene is good again");
                } else {
                    eprintln!("reloaded");
                }
                self.controls.reloaded(&scene);
                let view = self.controls.switches.view;
                self.controls.switches = Switches {
                    view,
                    exposure: self.config.exposure.unwrap_or(scene.image.exposure),
                    ..Switches::of_scene(&scene)
                };
                self.tone_operator = self.config.tonemap.unwrap_or(scene.image.tonemap);
                self.max_steps = scene.tracer.max_steps;
                if self.config.samples.is_none() {
                    self.schedule.samples = scene.image.samples.max(1);
                }
                let files = watched_files(self.config.scene_file.as_deref(), &scene);
                self.watch_files(&files);
                self.good_files = files;
                self.worker.send(Job::Scene(scene, self.controls.switches));
                self.ready = false;
                self.changed();
            }
            Err(e) => {
                eprintln!("error: {e}");
                self.error = Some(e);
                // the broken file's own mesh files too: saving a mesh it names but that was
                // missing must reload it, not only a save of the scene file
                if let Some(scene_file) = self.config.scene_file.clone() {
                    let mut files = self.good_files.clone();
                    if let Ok(source) = crate::scene::read::read_to_string(&scene_file) {
                        files.extend(Scene::mesh_files_named(
                            &source,
                            &scene_file,
                            &self.config.load_options,
                        ));
                    }
                    self.watch_files(&files);
                }
                self.compose();
            }
        }
    }

    /// Watches `files` from now on, unless they are the files watched already.
    fn watch_files(&mut self, files: &[PathBuf]) {
        if self.watch.as_ref().is_some_and(|w| w.watches(files)) {
            return;
        }
        match watch(files, &self.proxy) {
            Ok(w) => self.watch = w,
            Err(e) => eprintln!("error: {e}"),
        }
    }

    /// Runs script steps that are due; returns when the script waits.
    fn run_script(&mut self, event_loop: &ActiveEventLoop) {
        loop {
            let now = Instant::now();
            let Some(run) = &self.script else { return };
            if now < run.resume_at {
                return;
            }
            let Some(step) = run.steps.front().cloned() else {
                self.script = None;
                return;
            };
            let done = match step {
                Step::Wait(d) => {
                    if let Some(run) = &mut self.script {
                        run.resume_at = now + d;
                    }
                    true
                }
                Step::Converge => self.refined().is_some(),
                Step::WaitReload => {
                    let reloads = self.reloads;
                    let run = self.script.as_mut().expect("checked above");
                    let seen = *run.reloads_at_wait.get_or_insert(reloads);
                    if reloads != seen {
                        run.reloads_at_wait = None;
                    }
                    reloads != seen
                }
                Step::Input(i) => {
                    self.input(i);
                    true
                }
                Step::Stats => {
                    println!("{}", std::mem::take(&mut self.stats).describe());
                    true
                }
                Step::PrintCamera => {
                    self.act(Action::PrintCamera);
                    true
                }
                Step::Screenshot(path) => match self.refined().cloned() {
                    Some(fb) => {
                        if let Err(e) = self.write_screenshot(&path, &fb) {
                            return self.fail(event_loop, anyhow::anyhow!("{e}"));
                        }
                        true
                    }
                    None => false,
                },
                Step::WindowShot(path) => {
                    let (size, tone) = (self.controls.window, self.tone());
                    let shot = match (
                        self.presenter.as_mut(),
                        shown_picture(&self.composed, &self.shown, tone),
                    ) {
                        (Some(p), Some((shown, composed))) => Some(p.capture(
                            size,
                            &shown,
                            &HeadsUp {
                                text: &composed.heads_up,
                            },
                        )),
                        _ => None,
                    };
                    match shot {
                        Some(Ok(img)) => {
                            if let Err(e) = crate::render::output::save_png(&img, &path) {
                                return self.fail(event_loop, e);
                            }
                            true
                        }
                        Some(Err(e)) => {
                            return self.fail(event_loop, anyhow::anyhow!("window shot: {e}"));
                        }
                        None => false,
                    }
                }
                Step::Quit => {
                    self.quit = true;
                    true
                }
            };
            if !done {
                return;
            }
            if let Some(run) = &mut self.script {
                run.steps.pop_front();
            }
            if self.quit {
                return;
            }
        }
    }
}

impl ApplicationHandler<Wake> for Viewer {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_some() {
            return;
        }
        let (w, h) = self.controls.window;
        let attributes = Window::default_attributes()
            .with_title(format!("hytrace — {}", self.config.title))
            .with_inner_size(winit::dpi::PhysicalSize::new(w, h))
            .with_resizable(true);
        let window = match event_loop.create_window(attributes) {
            Ok(w) => Arc::new(w),
            Err(e) => return self.fail(event_loop, anyhow::anyhow!("cannot open a window: {e}")),
        };
        match Presenter::new(
            window.clone(),
            event_loop.owned_display_handle(),
            self.config.render_on_gpu,
        ) {
            Ok((p, gpu)) => {
                self.presenter = Some(p);
                if let Some(ctx) = gpu {
                    self.worker.send(Job::UseGpu(Box::new(ctx)));
                    self.ready = false;
                }
            }
            Err(e) => return self.fail(event_loop, anyhow::anyhow!("{e}")),
        }
        let size = window.inner_size();
        if size.width > 0 && size.height > 0 && (size.width, size.height) != (w, h) {
            self.controls.window = (size.width, size.height);
            self.changed();
        }
        self.window = Some(window);
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => self.quit = true,
            // a minimised window reports a size of zero: keep the last one
            WindowEvent::Resized(size) if size.width > 0 && size.height > 0 => {
                if let Some(p) = &mut self.presenter {
                    p.resize(size.width, size.height);
                }
                if (size.width, size.height) != self.controls.window {
                    self.controls.window = (size.width, size.height);
                    self.changed();
                    self.compose();
                }
            }
            WindowEvent::RedrawRequested => self.present(event_loop),
            WindowEvent::CursorMoved { position, .. } => self.input(Input::Move {
                x: position.x as f32,
                y: position.y as f32,
            }),
            WindowEvent::MouseInput { state, button, .. } => {
                let button = match button {
                    MouseButton::Left => Button::Left,
                    MouseButton::Middle => Button::Middle,
                    _ => return,
                };
                self.input(match state {
                    ElementState::Pressed => Input::Press(button),
                    ElementState::Released => Input::Release(button),
                });
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let notches = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    // touchpads scroll in pixels: about 40 to a notch
                    MouseScrollDelta::PixelDelta(p) => p.y as f32 / 40.0,
                };
                self.input(Input::Scroll(notches));
            }
            WindowEvent::ModifiersChanged(m) => self.input(Input::Shift(m.state().shift_key())),
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                let key = match &event.logical_key {
                    WinitKey::Named(NamedKey::Escape) => Key::Escape,
                    WinitKey::Named(NamedKey::F1) => Key::F1,
                    WinitKey::Character(s) => match s.chars().next() {
                        Some(c) => Key::Char(c.to_ascii_lowercase()),
                        None => return,
                    },
                    _ => return,
                };
                // held keys repeat for moving and exposure only, not for one-shot commands
                let repeats = matches!(
                    key,
                    Key::Char('w' | 'a' | 's' | 'd' | 'q' | 'e' | '+' | '=' | '-')
                );
                if !event.repeat || repeats {
                    self.input(Input::Key(key));
                }
            }
            _ => {}
        }
    }

    fn user_event(&mut self, _: &ActiveEventLoop, wake: Wake) {
        match wake {
            Wake::Worker(r) => self.report(r),
            Wake::FilesChanged => {
                // editors write a file in several steps: load once they have finished
                self.reload_at = Some(Instant::now() + Duration::from_millis(100));
            }
            // loads run side by side: one slower than a later one (a large mesh saved and then
            // taken out again) must not replace the later one's scene, which is on disk now
            Wake::Loaded(number, result) if number == self.reloads_started => self.loaded(result),
            Wake::Loaded(..) => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_none() {
            return;
        }
        if self.reload_at.is_some_and(|t| Instant::now() >= t) {
            self.reload_at = None;
            self.reload();
        }
        self.run_script(event_loop);
        // N frames shown, or fewer once no more will come: a converged image is not
        // rendered again until something changes (waiting for the Nth frame there hung)
        let settled = self.schedule.converged()
            && self.in_flight.is_none()
            && self.reload_at.is_none()
            && self.script.is_none()
            && self.frames_shown > 0;
        if self
            .config
            .frames
            .is_some_and(|n| self.frames_shown >= n || settled)
        {
            self.quit = true;
        }
        if self.quit {
            event_loop.exit();
            return;
        }
        self.schedule_frame();
        let wake = [
            self.reload_at,
            self.script.as_ref().map(|s| s.resume_at),
            self.schedule.wake_at(),
        ]
        .into_iter()
        .flatten()
        .min();
        event_loop.set_control_flow(match wake {
            Some(t) if t > Instant::now() => ControlFlow::WaitUntil(t),
            Some(_) => ControlFlow::WaitUntil(Instant::now() + Duration::from_millis(5)),
            None => ControlFlow::Wait,
        });
    }
}

/// The scene file and the mesh files it names.
fn watched_files(scene_file: Option<&Path>, scene: &Scene) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = scene_file.map(Path::to_path_buf).into_iter().collect();
    files.extend(scene.meshes.files().into_iter().map(Path::to_path_buf));
    files
}

fn watch(files: &[PathBuf], proxy: &EventLoopProxy<Wake>) -> anyhow::Result<Option<FileWatch>> {
    if files.is_empty() {
        return Ok(None);
    }
    let proxy = proxy.clone();
    FileWatch::new(files, move || {
        let _ = proxy.send_event(Wake::FilesChanged);
    })
    .map(Some)
    .map_err(|e| anyhow::anyhow!(e))
}

/// The picture of a frame and the window's heads-up band, as the display draws them.
fn shown_picture<'a>(
    composed: &'a Option<Composed>,
    shown: &'a Option<(ShownFrame, Frame)>,
    tone: ToneMapping,
) -> Option<(Shown<'a>, &'a Composed)> {
    let composed = composed.as_ref()?;
    let (frame, _) = shown.as_ref()?;
    let picture = match (&composed.pixels, &frame.on_device) {
        (Some((width, height, rgba)), _) => Shown::Pixels {
            rgba,
            width: *width,
            height: *height,
        },
        (None, Some(sums)) => Shown::Sums {
            buffer: &sums.buffer,
            passes: sums.passes,
            width: sums.width,
            height: sums.height,
            tone,
        },
        (None, None) => return None,
    };
    Some((picture, composed))
}

fn rgb_to_rgba(img: &RgbImage) -> Vec<u8> {
    let mut out = Vec::with_capacity(img.as_raw().len() / 3 * 4);
    for p in img.as_raw().chunks_exact(3) {
        out.extend_from_slice(&[p[0], p[1], p[2], 255]);
    }
    out
}

/// `text` cut into lines of at most `width` characters (an error can be long).
fn wrap(text: &str, width: usize) -> Vec<String> {
    let width = width.max(1);
    let mut lines: Vec<String> = Vec::new();
    let mut line = String::new();
    for word in text.split(' ') {
        let fits = line.chars().count() + 1 + word.chars().count() <= width;
        if !line.is_empty() && !fits {
            lines.push(std::mem::take(&mut line));
        }
        if !line.is_empty() {
            line.push(' ');
        }
        line.push_str(word);
        // a word longer than a line is cut
        while line.chars().count() > width {
            let head: String = line.chars().take(width).collect();
            line = line.chars().skip(width).collect();
            lines.push(head);
        }
    }
    if !line.is_empty() {
        lines.push(line);
    }
    lines.truncate(6);
    lines
}
