//! The headless wgpu device: adapter selection (CPU adapters such as lavapipe accepted), buffer
//! creation and read-back.

use super::GpuError;
use wgpu::util::DeviceExt;

/// The smallest storage buffer created: larger than any record of [`super::records`].
pub const MIN_STORAGE_BYTES: usize = 512;
// An empty buffer is bound as one zeroed record: the smallest buffer must hold the largest.
const _: () = assert!(size_of::<super::records::TriBlockRecord>() <= MIN_STORAGE_BYTES);
const _: () = assert!(size_of::<super::records::WideNodeRecord>() <= MIN_STORAGE_BYTES);

/// A wgpu device and queue (cloning shares them).
#[derive(Clone)]
pub struct GpuContext {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
}

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
        })
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
