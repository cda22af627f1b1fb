//! The peer renderer: our SSA tapes converted to fidget trees and rendered by fidget's voxel
//! renderers (VM and JIT on the CPU, wgpu on the GPU).
//!
//! Conversion, operation by operation (`to_tree` from SSA, `tape_to_tree` from the compiled
//! register tapes the tracer runs, both through `op_tree`): fidget has every elementary operation of
//! ours except four, which are written with its own:
//!
//! - `Select` (c > 0 ? a : b): with m = max(compare(c, 0), 0), which is 1 where c > 0 and 0
//!   elsewhere, `or(and(m, a), and(not(m), b))`. fidget's `and(x, y)` is x where x = 0, else y;
//!   `or(x, y)` is x where x ≠ 0, else y: so where m = 1 the result is a (even a = 0, since the
//!   second term is then 0), where m = 0 it is b. Its interval evaluator prunes the unused
//!   branch, as ours does. Only a NaN condition differs (we take b, fidget a).
//! - `Hypot`, `Hypot3`: `sqrt(a² + b²)` and `sqrt((a² + b²) + c²)`, the order our tape rounds in.
//! - `Pow` / `PowImm` (a ≥ 0): `exp(b · ln a)`, the formula of our tape; a constant exponent 0
//!   is the constant 1 (our a⁰ = 1).
//! - the `…Imm` forms become the operation with a constant.
//!
//! `tests/peer_conversion.rs` compares fidget's point evaluator with our tape at random points.

use super::{PeerModel, mask_of};
use crate::sdf::ssa::SsaTape;
use crate::sdf::tape::{MAX_REGISTERS, Op, Shape as OpShape, Tape};
use fidget::context::Tree;
use fidget::render::{ThreadPool, VoxelSize};
use fidget::shape::Shape;
use std::time::Instant;

/// The distance of `tape` as a fidget tree (material operations left out).
pub fn to_tree(tape: &SsaTape) -> Tree {
    let d = tape.distance_only();
    let live = d.live();
    let mut t: Vec<Option<Tree>> = vec![None; d.ops.len()];
    let (x, y, z) = Tree::axes();
    for (i, op) in d.ops.iter().enumerate() {
        if !live[i] {
            continue;
        }
        let get = |v: u32| {
            t.get(v as usize)
                .and_then(Clone::clone)
                .unwrap_or_else(|| Tree::constant(f32::NAN))
        };
        let tree = match op.op {
            Op::Input => match op.imm {
                0 => x.clone(),
                1 => y.clone(),
                _ => z.clone(),
            },
            Op::Pow => pow(
                get(op.a),
                get(op.b),
                d.ops.get(op.b as usize).and_then(constant),
            ),
            _ => op_tree(op.op, || get(op.a), || get(op.b), || get(op.c), op.imm()),
        };
        t[i] = Some(tree);
    }
    t.get(d.result as usize)
        .and_then(Clone::clone)
        .unwrap_or_else(|| Tree::constant(f32::NAN))
}

/// One operation of ours on fidget trees (`Pow` with a constant exponent is [`pow`]'s job:
/// the caller knows whether `b` is constant; `Input` is the caller's too).
fn op_tree(
    op: Op,
    a: impl Fn() -> Tree,
    b: impl Fn() -> Tree,
    c: impl Fn() -> Tree,
    k: f32,
) -> Tree {
    match op {
        Op::Const => Tree::constant(k),
        Op::Copy => a(),
        Op::Neg => a().neg(),
        Op::Abs => a().abs(),
        Op::Sqrt => a().sqrt(),
        Op::Square => a().square(),
        Op::Floor => a().floor(),
        Op::Sin => a().sin(),
        Op::Cos => a().cos(),
        Op::Tan => a().tan(),
        Op::Exp => a().exp(),
        Op::Ln => a().ln(),
        Op::Add => a() + b(),
        Op::Sub => a() - b(),
        Op::Mul => a() * b(),
        Op::Div => a() / b(),
        Op::Min => a().min(b()),
        Op::Max => a().max(b()),
        Op::Pow => pow(a(), b(), None),
        Op::Hypot => (a().square() + b().square()).sqrt(),
        Op::AddImm => a() + k,
        Op::SubImm => a() - k,
        Op::RsubImm => Tree::constant(k) - a(),
        Op::MulImm => a() * k,
        Op::DivImm => a() / k,
        Op::RdivImm => Tree::constant(k) / a(),
        Op::MinImm => a().min(k),
        Op::MaxImm => a().max(k),
        Op::PowImm => pow(a(), Tree::constant(k), Some(k)),
        Op::Select => {
            let m = c().compare(0.0).max(0.0);
            m.and(a()).or(m.not().and(b()))
        }
        Op::Hypot3 => ((a().square() + b().square()) + c().square()).sqrt(),
        // Not in a distance program (`Input` is handled by the callers).
        Op::MatLoad | Op::MatMix | Op::Input => Tree::constant(0.0),
    }
}

/// The distance of a compiled register [`Tape`] as a fidget tree: the very program the tracer
/// runs (the whole tape, or a leaf's specialised one), instruction by instruction, with the
/// formulas of [`to_tree`]. Registers 0–2 start as x, y, z; material instructions are skipped
/// as the interpreter skips them. Fails on a tape that reads a register no instruction wrote.
pub fn tape_to_tree(tape: &Tape) -> anyhow::Result<Tree> {
    let (x, y, z) = Tree::axes();
    let mut regs: Vec<Option<Tree>> = vec![None; MAX_REGISTERS];
    // What each register holds when it is a constant, for `Pow`'s exponent.
    let mut konst: Vec<Option<f32>> = vec![None; MAX_REGISTERS];
    regs[0] = Some(x);
    regs[1] = Some(y);
    regs[2] = Some(z);
    let material = tape.material_registers() > 0;
    for (i, ins) in tape.instrs().iter().enumerate() {
        let op = ins.op();
        if op.is_material() {
            if material {
                continue;
            }
            anyhow::bail!("instruction {i}: {op:?} in a distance tape");
        }
        let read = |r: u8| {
            regs[r as usize].clone().ok_or_else(|| {
                anyhow::anyhow!("instruction {i} ({op:?}) reads register {r} before any write")
            })
        };
        let (a, b, c) = match op.shape() {
            OpShape::Nullary => (None, None, None),
            OpShape::Unary | OpShape::WithImm => (Some(read(ins.a())?), None, None),
            OpShape::Binary => (Some(read(ins.a())?), Some(read(ins.b())?), None),
            OpShape::Ternary => (
                Some(read(ins.a())?),
                Some(read(ins.b())?),
                Some(read(ins.imm_bits() as u8)?),
            ),
            OpShape::MatLoad | OpShape::MatMix => (None, None, None),
        };
        let nan = || Tree::constant(f32::NAN);
        let (a, b, c) = (
            || a.clone().unwrap_or_else(nan),
            || b.clone().unwrap_or_else(nan),
            || c.clone().unwrap_or_else(nan),
        );
        let tree = match op {
            Op::Input => anyhow::bail!("instruction {i}: Input in a compiled tape"),
            Op::Pow => pow(a(), b(), konst[ins.b() as usize]),
            _ => op_tree(op, a, b, c, ins.imm()),
        };
        let out = ins.out() as usize;
        konst[out] = (op == Op::Const).then(|| ins.imm());
        regs[out] = Some(tree);
    }
    regs[tape.result() as usize]
        .clone()
        .ok_or_else(|| anyhow::anyhow!("the result register {} is never written", tape.result()))
}

fn constant(op: &crate::sdf::ssa::SsaOp) -> Option<f32> {
    (op.op == Op::Const).then(|| op.imm())
}

/// aᵇ for a ≥ 0 as our tape computes it.
fn pow(a: Tree, b: Tree, constant_b: Option<f32>) -> Tree {
    if constant_b == Some(0.0) {
        Tree::constant(1.0)
    } else {
        (b * a.ln()).exp()
    }
}

/// One of fidget's CPU evaluators.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Evaluator {
    /// The bytecode interpreter (`VmFunction`).
    Vm,
    /// The JIT (`JitFunction`).
    Jit,
}

/// A fidget shape ready to render: the view and the converted expression.
pub struct Prepared {
    vm: Shape<fidget::vm::VmFunction>,
    jit: Shape<fidget::jit::JitFunction>,
    config: fidget::raster::voxel::RenderConfig,
    /// Seconds to convert the tapes and build the VM shape.
    pub vm_build: f64,
    /// Seconds to convert the tapes and build (compile) the JIT shape.
    pub jit_build: f64,
}

/// The distance programs fidget is given: each object of the file lowered whole (a union
/// that hytrace traces as its members is one balanced tree of them, as fidget's interval
/// pruning wants it, not a chain of its parts' minima).
pub fn programs_of(model: &PeerModel) -> Vec<SsaTape> {
    (model.nodes.iter())
        .map(|(name, node)| {
            crate::sdf::lower(node, &|_| Some(0), 0)
                .unwrap_or_else(|e| panic!("{name} was lowered before: {e}"))
                .program
        })
        .collect()
}

/// The min of the programs' converted distances.
pub fn tree_of(programs: &[SsaTape]) -> Tree {
    let mut trees = programs.iter().map(to_tree);
    let first = trees.next().unwrap_or_else(|| Tree::constant(1.0));
    trees.fold(first, |acc, t| acc.min(t))
}

/// The render configuration of `model`'s view: fidget's voxel grid of side `size` mapped onto
/// the view cube so that its x, y sample positions are our pixel centres (fidget samples at
/// voxel corners, −1 + i·s in its own [−1, 1]³, and counts rows from the top).
fn config(model: &PeerModel) -> fidget::raster::voxel::RenderConfig {
    let n = model.size;
    let s = 2.0 / n as f32;
    let v = &model.view;
    let shift = nalgebra::Vector3::new(
        v.center.x + v.half * 0.5 * s,
        v.center.y + v.half * 0.5 * s,
        v.center.z + v.half * 0.5 * s,
    );
    fidget::raster::voxel::RenderConfig {
        image_size: VoxelSize::from(n),
        world_to_model: nalgebra::Matrix4::new_translation(&shift)
            * nalgebra::Matrix4::new_scaling(v.half),
    }
}

impl Prepared {
    /// Converts and builds both CPU shapes of `model`.
    pub fn new(model: &PeerModel) -> Prepared {
        let programs = programs_of(model);
        let start = Instant::now();
        let vm = Shape::<fidget::vm::VmFunction>::from(tree_of(&programs));
        let vm_build = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let jit = Shape::<fidget::jit::JitFunction>::from(tree_of(&programs));
        let jit_build = start.elapsed().as_secs_f64();
        Prepared {
            vm,
            jit,
            config: config(model),
            vm_build,
            jit_build,
        }
    }

    /// Renders the view (depth and normals) with `evaluator` on `pool` (None: the calling
    /// thread alone); returns the seconds and the hit mask (row-major, top row first), or None
    /// when the frame took longer than `limit` seconds (it is then cancelled).
    pub fn render(
        &self,
        evaluator: Evaluator,
        pool: Option<&ThreadPool>,
        limit: f64,
    ) -> anyhow::Result<Option<(f64, Vec<bool>)>> {
        let cancel = fidget::render::CancelToken::new();
        let eval = fidget::raster::voxel::EvalConfig {
            threads: pool,
            cancel: cancel.clone(),
            ..Default::default()
        };
        // A watchdog cancels the render at the limit (fidget checks the token between tiles).
        let (done, wait) = std::sync::mpsc::channel::<()>();
        let limit = std::time::Duration::from_secs_f64(limit.max(0.0));
        let watchdog = std::thread::spawn(move || {
            if let Err(std::sync::mpsc::RecvTimeoutError::Timeout) = wait.recv_timeout(limit) {
                cancel.cancel();
            }
        });
        let start = Instant::now();
        let image = match evaluator {
            Evaluator::Vm => {
                fidget::raster::voxel::render(self.vm.clone().try_into()?, &self.config, &eval)
            }
            Evaluator::Jit => {
                fidget::raster::voxel::render(self.jit.clone().try_into()?, &self.config, &eval)
            }
        };
        let seconds = start.elapsed().as_secs_f64();
        drop(done);
        let _ = watchdog.join();
        Ok(image.map(|image| (seconds, mask_of(image.iter().map(|p| p.depth > 0)))))
    }
}

/// A rayon pool for fidget, or None for one thread (fidget then renders on the caller's
/// thread).
pub fn pool(threads: usize) -> anyhow::Result<Option<ThreadPool>> {
    if threads <= 1 {
        return Ok(None);
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| anyhow::anyhow!("cannot start {threads} threads: {e}"))?;
    Ok(Some(ThreadPool::Custom(pool)))
}

/// fidget's wgpu voxel renderer on our device: pipelines, the shape's bytecode and buffers.
pub struct GpuPeer {
    context: fidget::wgpu::voxel::Context,
    shape: fidget::wgpu::RenderShape,
    workspace: fidget::wgpu::voxel::Workspace,
    out: fidget::wgpu::buf::ReadBuffer<fidget::wgpu::voxel::GeomBufferTag>,
    config: fidget::raster::voxel::RenderConfig,
}

impl GpuPeer {
    /// Builds the pipelines and uploads the shape (what a first frame costs beyond the render).
    pub fn new(ctx: &crate::gpu::context::GpuContext, model: &PeerModel) -> anyhow::Result<Self> {
        let gpu = fidget::wgpu::Gpu {
            device: ctx.device.clone(),
            queue: ctx.queue.clone(),
        };
        let context = fidget::wgpu::voxel::Context::new(&gpu);
        let vm = fidget::vm::VmShape::from(tree_of(&programs_of(model)));
        let shape = fidget::wgpu::RenderShape::new(&vm)?;
        let mut workspace = context.workspace();
        let out = gpu.read_buffer_for(workspace.output());
        Ok(GpuPeer {
            context,
            shape,
            workspace,
            out,
            config: config(model),
        })
    }

    /// Renders once (blocking until the image is back on the CPU); returns the seconds and the
    /// hit mask.
    pub fn render(&mut self) -> anyhow::Result<(f64, Vec<bool>)> {
        let start = Instant::now();
        let image =
            self.context
                .run(&self.shape, &mut self.workspace, &mut self.out, self.config)?;
        let seconds = start.elapsed().as_secs_f64();
        Ok((seconds, mask_of(image.iter().map(|p| p.depth > 0))))
    }
}
