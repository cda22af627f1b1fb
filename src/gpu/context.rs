//! The headless wgpu device: adapter selection (CPU adapters such as lavapipe accepted), buffer
//! creation and read-back.

use super::GpuError;
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};
use wgpu::util::DeviceExt;

/// The smallest storage buffer created: larger than any record of [`super::records`].
pub const MIN_STORAGE_BYTES: usize = 512;
// An empty buffer is bound as one zeroed record: the smallest buffer must hold the largest.
const _: () = assert!(size_of::<super::records::TriBlockRecord>() <= MIN_STORAGE_BYTES);
const _: () = assert!(size_of::<super::records::WideNodeRecord>() <= MIN_STORAGE_BYTES);

/// A wgpu device and queue (cloning shares them, and the compiled pipelines).
#[derive(Clone)]
pub struct GpuContext {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    pipelines: Arc<Mutex<HashMap<PipelineKey, Arc<PipelineSlot>>>>,
}

/// A compute pipeline and the bind group layouts it was created with (group 0 first).
#[derive(Clone, Debug)]
pub struct ComputePipeline {
    /// The pipeline.
    pub pipeline: wgpu::ComputePipeline,
    /// Its bind group layouts, by group.
    pub layouts: Vec<wgpu::BindGroupLayout>,
}

/// A module's text and entry point: what makes two pipelines the same.
type PipelineKey = (String, String);
/// A pipeline being compiled or compiled (or the message of its failure), filled once.
type PipelineSlot = OnceLock<Result<ComputePipeline, String>>;

impl GpuContext {
    /// Opens the first Vulkan adapter wgpu offers, software ones (llvmpipe) included, with the
    /// adapter's own limits (the scene library binds more storage buffers than the WebGPU
    /// default of 8). Fails with [`GpuError::NoAdapter`] when there is none.
    pub fn new() -> Result<Self, GpuError> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::VULKAN,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        }))
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        Self::with_adapter(&adapter)
    }

    /// Opens a device for the tracer on `adapter` (one that can also present to a window,
    /// say) with the adapter's own limits; fails when they are too small for the tracer.
    pub fn with_adapter(adapter: &wgpu::Adapter) -> Result<Self, GpuError> {
        Self::open(adapter, true)
    }

    /// Opens a device on `adapter` to draw pictures with (no tracing, so no limit is checked).
    pub fn for_drawing(adapter: &wgpu::Adapter) -> Result<Self, GpuError> {
        Self::open(adapter, false)
    }

    fn open(adapter: &wgpu::Adapter, for_tracing: bool) -> Result<Self, GpuError> {
        let info = adapter.get_info();
        let limits = adapter.limits();
        let needed = super::shaders::scene_bindings().len() as u32 + 3;
        if for_tracing && limits.max_storage_buffers_per_shader_stage < needed {
            return Err(GpuError::Unsupported(format!(
                "adapter `{}` binds at most {} storage buffers per shader stage, the GPU tracer \
                 needs {needed}",
                info.name, limits.max_storage_buffers_per_shader_stage
            )));
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("hytrace"),
            required_features: wgpu::Features::empty(),
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device(e.to_string()))?;
        Ok(GpuContext {
            device,
            queue,
            info,
            limits,
            pipelines: Arc::default(),
        })
    }

    /// The compute pipeline of `source`'s `entry` over bind groups of `layouts`, compiled on
    /// the first request and shared by every later one (with the layouts it was made with)
    /// on this context and its clones; a module that fails validation fails as
    /// [`GpuError::Shader`] named `label`, every time.
    ///
    /// Why a cache: a driver compiles a pipeline in full at each creation and wgpu does not
    /// share equal ones. The scene library is one large module: lavapipe takes 3–9 s to
    /// create one of its pipelines even with Mesa's shader cache warm, and every scene's
    /// query, probe or renderer paid that again. Requests for different modules compile side
    /// by side; requests for one being compiled wait for it. The cache keeps one entry per
    /// module text and entry point: the product's kernels are a handful of fixed texts.
    pub fn compute_pipeline(
        &self,
        label: &str,
        source: &str,
        entry: &str,
        layouts: impl FnOnce() -> Vec<wgpu::BindGroupLayout>,
    ) -> Result<ComputePipeline, GpuError> {
        let slot = {
            // A poisoned map is still whole: slots are only ever added.
            let mut map = self.pipelines.lock().unwrap_or_else(|e| e.into_inner());
            map.entry((source.to_string(), entry.to_string()))
                .or_default()
                .clone()
        };
        slot.get_or_init(|| self.create_compute_pipeline(label, source, entry, layouts()))
            .clone()
            .map_err(|message| GpuError::Shader {
                name: label.to_string(),
                message,
            })
    }

    fn create_compute_pipeline(
        &self,
        label: &str,
        source: &str,
        entry: &str,
        layouts: Vec<wgpu::BindGroupLayout>,
    ) -> Result<ComputePipeline, String> {
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        let groups: Vec<Option<&wgpu::BindGroupLayout>> = layouts.iter().map(Some).collect();
        let layout = self
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &groups,
                immediate_size: 0,
            });
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: Some(&layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            });
        match pollster::block_on(scope.pop()) {
            Some(e) => Err(e.to_string()),
            None => Ok(ComputePipeline { pipeline, layouts }),
        }
    }

    /// The adapter's name, e.g. `llvmpipe (LLVM 15.0.6, 256 bits)`.
    pub fn adapter_name(&self) -> &str {
        &self.info.name
    }

    /// The adapter's description (name, backend, device type).
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.info
    }

    /// The device limits in force.
    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// A storage buffer holding `bytes`, zero-padded to at least [`MIN_STORAGE_BYTES`]: a
    /// binding must hold one element of its array, so an empty list is uploaded as a zeroed
    /// record that no index reaches.
    pub fn storage_buffer(&self, label: &str, bytes: &[u8], writable: bool) -> wgpu::Buffer {
        let mut usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        if writable {
            usage |= wgpu::BufferUsages::COPY_SRC;
        }
        let padded;
        let contents = if bytes.len() < MIN_STORAGE_BYTES {
            padded = [
                bytes,
                &[0u8; MIN_STORAGE_BYTES][..MIN_STORAGE_BYTES - bytes.len()],
            ]
            .concat();
            &padded[..]
        } else {
            bytes
        };
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
    }

    /// A uniform buffer holding `bytes`, writable from the queue.
    pub fn uniform_buffer(&self, label: &str, bytes: &[u8]) -> wgpu::Buffer {
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytes,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            })
    }

    /// Copies the first `size` bytes of `buffer` (which needs `COPY_SRC`) back to the host.
    pub fn read_buffer(&self, buffer: &wgpu::Buffer, size: u64) -> Result<Vec<u8>, GpuError> {
        if size == 0 {
            return Ok(Vec::new());
        }
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("hytrace read-back"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
        self.queue.submit([encoder.finish()]);
        let slice = staging.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|e| GpuError::ReadBack(e.to_string()))?
            .map_err(|e| GpuError::ReadBack(e.to_string()))?;
        let data = slice
            .get_mapped_range()
            .map_err(|e| GpuError::ReadBack(format!("{e:?}")))?
            .to_vec();
        staging.unmap();
        Ok(data)
    }

    /// Blocks until the queue has finished its work.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| GpuError::Device(e.to_string()))
    }
}
