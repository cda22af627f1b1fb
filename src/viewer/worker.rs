//! The viewer's render thread: it owns the scene and its tracer (built once per scene, kept
//! across frames and switches), renders the frames the window asks for, and abandons a frame
//! as soon as a newer one is wanted. Frames render on the CPU, or on a GPU through the same
//! sample passes `hytrace render --backend gpu` adds up.

use super::session::Switches;
use crate::gpu::context::GpuContext;
use crate::gpu::render::{GpuPasses, GpuRenderer, PreparedScene};
use crate::render::progressive::SampleSums;
use crate::render::{Framebuffer, RenderOptions, cpu};
use crate::scene::camera::Camera;
use crate::scene::{AmbientOcclusion, Scene};
use crate::trace::{SceneTracer, TracerParts};
use glam::Vec3;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::time::{Duration, Instant};

/// Work for the render thread.
pub enum Job {
    /// Render one sample of every pixel. `samples` is the sample count of the refined image
    /// (which fixes where sample `sample` sits); sample 0 starts a new accumulation.
    Frame {
        /// The change this frame belongs to; a newer [`Worker::want`] abandons it.
        generation: u64,
        /// The camera.
        camera: Camera,
        /// Image size and samples.
        options: RenderOptions,
        /// Which sample.
        sample: u32,
        /// Whether the window needs the frame on the host (a debug view, say). A CPU frame is
        /// there anyway; a GPU frame otherwise stays on the device but for the last sample
        /// of a refinement, which screenshots write.
        read_back: bool,
    },
    /// Render on this GPU from now on (the device that presents the window).
    UseGpu(Box<GpuContext>),
    /// Find the first surface along the camera ray through (u, v) of an image of `aspect`.
    Pick {
        /// The camera.
        camera: Camera,
        /// Normalised image position.
        u: f32,
        /// Normalised image position.
        v: f32,
        /// Width / height.
        aspect: f32,
    },
    /// Trace with these switches from now on.
    Switches(Switches),
    /// Trace this scene from now on (a reload).
    Scene(Box<Scene>, Switches),
}

/// What the render thread reports.
pub enum Report {
    /// A frame: the mean over the samples accumulated so far (one for a preview).
    Frame {
        /// The change it belongs to.
        generation: u64,
        /// Which sample was added.
        sample: u32,
        /// The image on the host: every CPU frame, and GPU frames read back.
        image: Option<Box<Framebuffer>>,
        /// A GPU frame's sums where the render kernel left them.
        on_device: Option<DeviceSums>,
        /// Time the frame took to render.
        elapsed: Duration,
    },
    /// A frame was abandoned for a newer one.
    Abandoned,
    /// The answer to a pick: the hit point, if the ray hit.
    Picked(Option<Vec3>),
    /// The GPU could not render a frame or prepare a scene: the window shows why.
    Failed(String),
    /// The tracer of a new scene or new switches is ready.
    Ready {
        /// Time taken to build it (zero when structures were reused).
        build: Duration,
        /// Which backend renders.
        backend: String,
    },
}

/// The sums of a GPU frame, on the device that presents the window: a copy made for the
/// window, which later passes do not touch.
pub struct DeviceSums {
    /// One `RenderPixel` per pixel, row-major.
    pub buffer: wgpu::Buffer,
    /// Samples summed.
    pub passes: u32,
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
}

/// The window's handle on the render thread.
pub struct Worker {
    jobs: Sender<Job>,
    wanted: Arc<AtomicU64>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Worker {
    /// Starts the render thread on `scene`, with `threads` rayon workers (None: all cores),
    /// rendering frames on `gpu` when one is given and on the CPU otherwise; every report
    /// goes to `report`, which must not block.
    pub fn start(
        scene: Scene,
        switches: Switches,
        threads: Option<usize>,
        gpu: Option<GpuContext>,
        report: impl Fn(Report) + Send + 'static,
    ) -> anyhow::Result<Worker> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.unwrap_or(0))
            .thread_name(|i| format!("hytrace render {i}"))
            .build()?;
        let (jobs, inbox) = channel();
        let wanted = Arc::new(AtomicU64::new(0));
        let want = wanted.clone();
        let thread = std::thread::Builder::new()
            .name("hytrace render".into())
            .spawn(move || {
                serve(
                    scene,
                    switches,
                    &pool,
                    gpu.map(GpuFrames::new),
                    &inbox,
                    &want,
                    &report,
                )
            })?;
        Ok(Worker {
            jobs,
            wanted,
            thread: Some(thread),
        })
    }

    /// Asks for work (ignored when the thread has gone).
    pub fn send(&self, job: Job) {
        let _ = self.jobs.send(job);
    }

    /// Says which change the window wants frames for now: a frame of an older one that is
    /// still rendering is abandoned within a tile.
    pub fn want(&self, generation: u64) {
        self.wanted.store(generation, Ordering::Relaxed);
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        // abandon whatever renders, close the inbox, and wait for the thread to leave
        self.wanted.store(u64::MAX, Ordering::Relaxed);
        let (closed, _) = channel();
        drop(std::mem::replace(&mut self.jobs, closed));
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Why the inner loop of [`serve`] ended.
enum Next {
    Switches(Switches),
    Gpu(Box<GpuContext>),
    Scene(Box<Scene>, Switches),
    Stop,
}

/// Frames on a GPU: its context, the compiled kernel, the scene uploaded for the current
/// switches, and the device-side sums of the refining image.
struct GpuFrames {
    ctx: GpuContext,
    renderer: GpuRenderer,
    prepared: Option<PreparedScene>,
    passes: Option<GpuPasses>,
}

impl GpuFrames {
    /// Frames on `ctx`: the kernel compiles once; scenes and switches only upload buffers.
    fn new(ctx: GpuContext) -> GpuFrames {
        GpuFrames {
            renderer: GpuRenderer::new(&ctx),
            ctx,
            prepared: None,
            passes: None,
        }
    }

    /// The adapter, for the heads-up line.
    fn describe(&self) -> String {
        format!("GPU {}", self.ctx.adapter_name())
    }

    /// Adds pass `sample` of `camera`'s image to the device-side sums; pass 0 starts them.
    fn add_pass(
        &mut self,
        camera: &Camera,
        options: &RenderOptions,
        sample: u32,
    ) -> anyhow::Result<()> {
        let Some(prepared) = &self.prepared else {
            anyhow::bail!("the scene is not on the GPU");
        };
        let size = (options.width, options.height);
        let mut passes = match self.passes.take() {
            Some(p) if (p.width(), p.height()) == size => p,
            _ => GpuPasses::new(&self.ctx, &self.renderer, size.0, size.1)?,
        };
        if sample == 0 {
            passes.clear();
        }
        let passes = self.passes.insert(passes);
        self.renderer
            .render_pass(&self.ctx, prepared, camera, options, sample, passes)
    }

    /// The passes added so far: a copy of their sums on the device, and their mean read
    /// back when `read_back` asks.
    fn frame(&self, read_back: bool) -> anyhow::Result<(Option<Framebuffer>, DeviceSums)> {
        let Some(p) = &self.passes else {
            anyhow::bail!("no pass was rendered");
        };
        let on_device = DeviceSums {
            buffer: p.snapshot(&self.ctx)?,
            passes: p.passes(),
            width: p.width(),
            height: p.height(),
        };
        let image = if read_back {
            Some(p.read(&self.ctx)?.mean())
        } else {
            None
        };
        Ok((image, on_device))
    }
}

/// The render thread's loop: a tracer per scene and switches, frames until either changes.
fn serve(
    mut scene: Scene,
    mut switches: Switches,
    pool: &rayon::ThreadPool,
    mut gpu: Option<GpuFrames>,
    inbox: &Receiver<Job>,
    wanted: &AtomicU64,
    report: &dyn Fn(Report),
) {
    let mut file_ao: Option<AmbientOcclusion> = scene.shading.ambient_occlusion;
    let mut parts: Option<TracerParts> = None;
    loop {
        switches.apply(&mut scene, file_ao);
        let start = Instant::now();
        let reused = parts.is_some();
        let tracer = match parts.take() {
            Some(p) => SceneTracer::with_parts(&scene, p),
            // built on the render threads, as cpu::render builds it
            None => pool.install(|| SceneTracer::new(&scene)),
        };
        // the CPU tracer serves picks on either backend
        let mut backend = "CPU".to_string();
        let mut on_gpu = None;
        if let Some(g) = gpu.as_mut() {
            g.passes = None;
            g.prepared = None;
            match g.renderer.prepare_with(&g.ctx, &tracer) {
                Ok(p) => {
                    g.prepared = Some(p);
                    backend = g.describe();
                    on_gpu = Some(g);
                }
                Err(e) => report(Report::Failed(format!(
                    "the GPU cannot take this scene, rendering it on the CPU: {e:#}"
                ))),
            }
        }
        report(Report::Ready {
            build: if reused {
                Duration::ZERO
            } else {
                start.elapsed()
            },
            backend,
        });
        let next = frames(&tracer, pool, on_gpu, inbox, wanted, report);
        match next {
            Next::Switches(s) => {
                switches = s;
                parts = Some(tracer.into_parts());
            }
            Next::Gpu(ctx) => {
                gpu = Some(GpuFrames::new(*ctx));
                parts = Some(tracer.into_parts());
            }
            Next::Scene(s, sw) => {
                drop(tracer);
                scene = *s;
                switches = sw;
                file_ao = scene.shading.ambient_occlusion;
            }
            Next::Stop => return,
        }
    }
}

/// Serves frames and picks with one tracer.
fn frames(
    tracer: &SceneTracer,
    pool: &rayon::ThreadPool,
    mut gpu: Option<&mut GpuFrames>,
    inbox: &Receiver<Job>,
    wanted: &AtomicU64,
    report: &dyn Fn(Report),
) -> Next {
    // the accumulation of the refined image: its change, size, samples added, and the CPU's
    // sums (made by the first CPU pass: the GPU accumulates on its own)
    let mut sums: Option<(u64, RenderOptions, u32, Option<SampleSums>)> = None;
    // The CPU sums of the last accumulation, kept for the next one of the same size: memory
    // new to the process costs a page fault per 4 KiB on first touch, and every rest of the
    // camera starts an accumulation at the window's size (a 640×360 image's sums are 11 MB;
    // one-sample previews have no sums).
    let mut spare: Option<SampleSums> = None;
    loop {
        let Ok(job) = inbox.recv() else {
            return Next::Stop;
        };
        match job {
            Job::Switches(s) => return Next::Switches(s),
            Job::UseGpu(ctx) => return Next::Gpu(ctx),
            Job::Scene(s, sw) => return Next::Scene(s, sw),
            Job::Pick {
                camera,
                u,
                v,
                aspect,
            } => {
                let ray = camera.ray(u, v, aspect);
                let hit = tracer.closest_hit(&ray, 0.0, f32::INFINITY);
                report(Report::Picked(hit.map(|h| ray.at(h.t))));
            }
            Job::Frame {
                generation,
                camera,
                options,
                sample,
                read_back,
            } => {
                let start = Instant::now();
                let cancelled = || wanted.load(Ordering::Relaxed) != generation;
                if gpu.is_none() && options.samples == 1 && sample == 0 {
                    // One sample is the whole image (a preview): the pass writes the image
                    // itself, the same bits as the mean of its sums, without the sums.
                    if let Some((_, _, _, Some(old))) = sums.take() {
                        spare = Some(old);
                    }
                    match pool
                        .install(|| cpu::render_single_pass(tracer, &camera, &options, &cancelled))
                    {
                        Some(image) => report(Report::Frame {
                            generation,
                            sample,
                            image: Some(Box::new(image)),
                            on_device: None,
                            elapsed: start.elapsed(),
                        }),
                        None => report(Report::Abandoned),
                    }
                    continue;
                }
                let continues = sums.as_ref().is_some_and(|(g, o, added, _)| {
                    sample != 0 && *g == generation && *o == options && *added == sample
                });
                if !continues {
                    // a new accumulation; when the one asked to continue is not there (a GPU
                    // fault fell back to the CPU), its earlier samples are rendered first
                    if let Some((_, _, _, Some(old))) = sums.take() {
                        spare = Some(old);
                    }
                    sums = Some((generation, options, 0, None));
                }
                let (_, _, added, acc) = sums.as_mut().expect("set above");
                let mut outcome = Ok(true);
                while outcome.as_ref().is_ok_and(|&done| done) && *added <= sample {
                    let pass = *added;
                    outcome = match gpu.as_deref_mut() {
                        // a GPU pass is not cut short; a stale one is dropped before it starts
                        Some(_) if cancelled() => Ok(false),
                        Some(g) => g.add_pass(&camera, &options, pass).map(|()| true),
                        None => {
                            let acc = acc.get_or_insert_with(|| match spare.take() {
                                Some(mut old)
                                    if (old.width, old.height)
                                        == (options.width, options.height) =>
                                {
                                    old.clear();
                                    old
                                }
                                _ => SampleSums::new(options.width, options.height),
                            });
                            Ok(pool.install(|| {
                                cpu::render_pass(tracer, &camera, &options, pass, acc, &cancelled)
                            }))
                        }
                    };
                    if outcome.as_ref().is_ok_and(|&done| done) {
                        *added += 1;
                    }
                }
                let last = sample + 1 >= options.samples;
                let image = match (outcome, gpu.as_deref_mut()) {
                    (Ok(true), Some(g)) => g
                        .frame(read_back || last)
                        .map(|(image, sums)| (image, Some(sums))),
                    (Ok(true), None) => Ok((
                        Some(acc.as_ref().expect("a CPU pass made the sums").mean()),
                        None,
                    )),
                    (Ok(false), _) => {
                        if let Some((_, _, _, Some(old))) = sums.take() {
                            spare = Some(old);
                        }
                        report(Report::Abandoned);
                        continue;
                    }
                    (Err(e), _) => Err(e),
                };
                match image {
                    Ok((image, on_device)) => report(Report::Frame {
                        generation,
                        sample,
                        image: image.map(Box::new),
                        on_device,
                        elapsed: start.elapsed(),
                    }),
                    Err(e) => {
                        report(Report::Failed(format!(
                            "the GPU failed to render a frame, rendering on the CPU from now \
                             on: {e:#}"
                        )));
                        gpu = None;
                        sums = None;
                        report(Report::Abandoned);
                    }
                }
            }
        }
    }
}
