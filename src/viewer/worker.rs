//! The viewer's render thread: it owns the scene and its tracer (built once per scene, kept
//! across frames and switches), renders the frames the window asks for, and abandons a frame
//! as soon as a newer one is wanted.

use super::session::Switches;
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
    },
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
        /// The image.
        image: Box<Framebuffer>,
        /// Time the frame took to render.
        elapsed: Duration,
    },
    /// A frame was abandoned for a newer one.
    Abandoned,
    /// The answer to a pick: the hit point, if the ray hit.
    Picked(Option<Vec3>),
    /// The tracer of a new scene or new switches is ready.
    Ready {
        /// Time taken to build it (zero when structures were reused).
        build: Duration,
        /// Which backend renders.
        backend: String,
    },
}

/// The window's handle on the render thread.
pub struct Worker {
    jobs: Sender<Job>,
    wanted: Arc<AtomicU64>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Worker {
    /// Starts the render thread on `scene`, with `threads` rayon workers (None: all cores);
    /// every report goes to `report`, which must not block.
    pub fn start(
        scene: Scene,
        switches: Switches,
        threads: Option<usize>,
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
            .spawn(move || serve(scene, switches, &pool, &inbox, &want, &report))?;
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
    Scene(Box<Scene>, Switches),
    Stop,
}

/// The render thread's loop: a tracer per scene and switches, frames until either changes.
fn serve(
    mut scene: Scene,
    mut switches: Switches,
    pool: &rayon::ThreadPool,
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
        report(Report::Ready {
            build: if reused {
                Duration::ZERO
            } else {
                start.elapsed()
            },
            backend: "CPU".into(),
        });
        let next = frames(&tracer, pool, inbox, wanted, report);
        match next {
            Next::Switches(s) => {
                switches = s;
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
    inbox: &Receiver<Job>,
    wanted: &AtomicU64,
    report: &dyn Fn(Report),
) -> Next {
    // the accumulation of the refined image: its change, size, samples added, sums
    let mut sums: Option<(u64, RenderOptions, u32, SampleSums)> = None;
    loop {
        let Ok(job) = inbox.recv() else {
            return Next::Stop;
        };
        match job {
            Job::Switches(s) => return Next::Switches(s),
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
            } => {
                let start = Instant::now();
                let fresh = match &sums {
                    Some((g, o, added, _)) => {
                        sample == 0 || *g != generation || *o != options || *added != sample
                    }
                    None => true,
                };
                if fresh {
                    if sample != 0 {
                        // an accumulation that is not there to continue: start again
                        report(Report::Abandoned);
                        continue;
                    }
                    sums = Some((
                        generation,
                        options,
                        0,
                        SampleSums::new(options.width, options.height),
                    ));
                }
                let (_, _, added, acc) = sums.as_mut().expect("set above");
                let cancelled = || wanted.load(Ordering::Relaxed) != generation;
                let rendered = pool.install(|| {
                    cpu::render_pass(tracer, &camera, &options, sample, acc, &cancelled)
                });
                if !rendered {
                    sums = None;
                    report(Report::Abandoned);
                    continue;
                }
                *added += 1;
                report(Report::Frame {
                    generation,
                    sample,
                    image: Box::new(acc.mean()),
                    elapsed: start.elapsed(),
                });
            }
        }
    }
}
