//! Implicit surfaces f(x, y, z) = 0 from expressions: lowering, a definedness check and the
//! Lipschitz estimate they are traced with (f/λ, clipped to their box).

use super::domain::{clip_lipschitz, project_box};
use super::emit::{Emit, V3};
use super::fmt3;
use super::shapes;
use crate::sdf::expr::{BinaryOp, Expr, UnaryOp};
use crate::sdf::ssa::{Builder, V};
use crate::sdf::tape::Op;
use glam::Vec3;

/// The clipped field of an implicit: max(f(π(p))/λ, box(p)) over the box [−h, h].
pub fn clipped(b: &mut Builder, e: &Expr, p: V3, h: Vec3, lambda: f32) -> V {
    let region = shapes::box_distance(b, p, h);
    let proj = project_box(b, p, h);
    let f = lower_expr(b, e, proj);
    clip_lipschitz(b, f, lambda, region)
}

/// Lowers an implicit-surface expression; integer powers become products so that negative
/// bases work identically on every backend (WGSL's pow is undefined for x < 0).
pub fn lower_expr(b: &mut Builder, e: &Expr, p: V3) -> V {
    match e {
        Expr::X => p.x(),
        Expr::Y => p.y(),
        Expr::Z => p.z(),
        Expr::Const(c) => b.konst(*c),
        Expr::Unary(op, a) => {
            let a = lower_expr(b, a, p);
            let op = match op {
                UnaryOp::Neg => Op::Neg,
                UnaryOp::Abs => Op::Abs,
                UnaryOp::Sqrt => Op::Sqrt,
                UnaryOp::Sin => Op::Sin,
                UnaryOp::Cos => Op::Cos,
                UnaryOp::Tan => Op::Tan,
                UnaryOp::Exp => Op::Exp,
                UnaryOp::Ln => Op::Ln,
                UnaryOp::Floor => Op::Floor,
            };
            b.unary(op, a)
        }
        Expr::Binary(BinaryOp::Pow, base, exp) => {
            let x = lower_expr(b, base, p);
            match **exp {
                Expr::Const(n) if n.fract() == 0.0 && n.abs() <= 64.0 => {
                    let k = n.abs() as u32;
                    let pos = int_pow(b, x, k);
                    if n < 0.0 { b.rdiv_k(1.0, pos) } else { pos }
                }
                _ => {
                    let y = lower_expr(b, exp, p);
                    b.binary(Op::Pow, x, y)
                }
            }
        }
        Expr::Binary(op, l, r) => {
            let l = lower_expr(b, l, p);
            let r = lower_expr(b, r, p);
            let op = match op {
                BinaryOp::Add => Op::Add,
                BinaryOp::Sub => Op::Sub,
                BinaryOp::Mul => Op::Mul,
                BinaryOp::Div => Op::Div,
                BinaryOp::Min => Op::Min,
                BinaryOp::Max => Op::Max,
                BinaryOp::Pow => unreachable!("handled above"),
            };
            b.binary(op, l, r)
        }
    }
}

/// xᵏ by repeated squaring.
fn int_pow(b: &mut Builder, x: V, k: u32) -> V {
    if k == 0 {
        return b.konst(1.0);
    }
    let (mut result, mut base, mut k) = (None, x, k);
    while k > 0 {
        if k & 1 == 1 {
            result = Some(match result {
                None => base,
                Some(r) => b.mul(r, base),
            });
        }
        k >>= 1;
        if k > 0 {
            base = b.square(base);
        }
    }
    result.expect("k > 0 sets the result")
}

/// Checks that an expression is finite over the box [−h, h] (sampled on a 21³ grid that
/// includes the faces): a NaN would silently turn part of the box into solid, since the clipped
/// field falls back to the box distance there.
pub fn check_defined(e: &Expr, h: Vec3) -> Result<(), String> {
    const N: usize = 21;
    for i in 0..N {
        for j in 0..N {
            for k in 0..N {
                let t = Vec3::new(i as f32, j as f32, k as f32) / (N - 1) as f32;
                let q = -h + 2.0 * h * t;
                let v = e.eval(q);
                if !v.is_finite() {
                    return Err(format!(
                        "the expression is {v} at {} inside its box; it must be defined \
                         everywhere in half_extents (e.g. guard sqrt and ln with abs or max)",
                        fmt3(q)
                    ));
                }
            }
        }
    }
    Ok(())
}

/// Estimates the Lipschitz constant of an expression over the box [−h, h] by the largest
/// central-difference gradient on a 25³ grid, times 1.5 for what the grid misses.
pub fn estimate_lipschitz(e: &Expr, h: Vec3) -> Result<f32, String> {
    let mut b = Builder::new();
    let p = V3(b.point());
    let f = lower_expr(&mut b, e, p);
    let tape = b.finish(f, None).compile()?;
    const N: usize = 25;
    let step = (2.0 * h.max_element() / N as f32) * 1e-2;
    let mut max_grad: f32 = 0.0;
    for i in 0..N {
        for j in 0..N {
            for k in 0..N {
                let t = (Vec3::new(i as f32, j as f32, k as f32) + 0.5) / N as f32;
                let q = -h + 2.0 * h * t;
                let g = tape.gradient(q, step).length();
                if g.is_finite() {
                    max_grad = max_grad.max(g);
                }
            }
        }
    }
    if max_grad > 0.0 {
        Ok(1.5 * max_grad)
    } else {
        Err(
            "could not estimate a Lipschitz constant (the gradient is zero or undefined on \
             the whole box); give `lipschitz:` explicitly"
                .to_string(),
        )
    }
}
