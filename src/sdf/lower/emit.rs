//! Shorthands the formulas are written in: scalar operations by name, and 3-vectors of SSA
//! values (a vector exists only while lowering; the tape is scalar).

use crate::sdf::ssa::{Builder, V};
use crate::sdf::tape::Op;
use glam::{Affine3A, Vec3};

/// A point or direction as three SSA values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct V3(pub [V; 3]);

impl V3 {
    /// Component i.
    pub fn at(self, i: usize) -> V {
        self.0[i]
    }
    /// x
    pub fn x(self) -> V {
        self.0[0]
    }
    /// y
    pub fn y(self) -> V {
        self.0[1]
    }
    /// z
    pub fn z(self) -> V {
        self.0[2]
    }
}

/// Named operations on scalars and 3-vectors.
pub trait Emit {
    /// a + b
    fn add(&mut self, a: V, b: V) -> V;
    /// a − b
    fn sub(&mut self, a: V, b: V) -> V;
    /// a · b
    fn mul(&mut self, a: V, b: V) -> V;
    /// a / b
    fn div(&mut self, a: V, b: V) -> V;
    /// min(a, b)
    fn min(&mut self, a: V, b: V) -> V;
    /// max(a, b)
    fn max(&mut self, a: V, b: V) -> V;
    /// a + k
    fn add_k(&mut self, a: V, k: f32) -> V;
    /// a − k
    fn sub_k(&mut self, a: V, k: f32) -> V;
    /// k − a
    fn rsub_k(&mut self, k: f32, a: V) -> V;
    /// a · k
    fn mul_k(&mut self, a: V, k: f32) -> V;
    /// a / k
    fn div_k(&mut self, a: V, k: f32) -> V;
    /// k / a
    fn rdiv_k(&mut self, k: f32, a: V) -> V;
    /// min(a, k)
    fn min_k(&mut self, a: V, k: f32) -> V;
    /// max(a, k)
    fn max_k(&mut self, a: V, k: f32) -> V;
    /// clamp(a, lo, hi) = min(max(a, lo), hi)
    fn clamp_k(&mut self, a: V, lo: f32, hi: f32) -> V;
    /// −a
    fn neg(&mut self, a: V) -> V;
    /// |a|
    fn abs(&mut self, a: V) -> V;
    /// √a
    fn sqrt(&mut self, a: V) -> V;
    /// a²
    fn square(&mut self, a: V) -> V;
    /// ⌊a⌋
    fn floor(&mut self, a: V) -> V;
    /// (c > 0) ? a : b
    fn pick(&mut self, c: V, a: V, b: V) -> V;
    /// The constant k.
    fn k(&mut self, k: f32) -> V;
    /// √(Σ vᵢ²), as one `Hypot` or `Hypot3`.
    fn length(&mut self, v: &[V]) -> V;
    /// Σ vᵢ·cᵢ, zero coefficients skipped (exact for finite v).
    fn dot_k(&mut self, v: V3, c: Vec3) -> V;
    /// The largest component.
    fn max_of(&mut self, v: &[V]) -> V;
    /// Componentwise v − c.
    fn v_sub_k(&mut self, v: V3, c: Vec3) -> V3;
    /// Componentwise v + c.
    fn v_add_k(&mut self, v: V3, c: Vec3) -> V3;
    /// Componentwise v / c.
    fn v_div_k(&mut self, v: V3, c: Vec3) -> V3;
    /// Componentwise |v|.
    fn v_abs(&mut self, v: V3) -> V3;
    /// Componentwise max(v, k).
    fn v_max_k(&mut self, v: V3, k: f32) -> V3;
    /// M·v + t, with zero and unit coefficients of the matrix taken as such (exact for finite
    /// v): a translation costs three additions.
    fn affine(&mut self, v: V3, m: &Affine3A) -> V3;
}

impl Emit for Builder {
    fn add(&mut self, a: V, b: V) -> V {
        self.binary(Op::Add, a, b)
    }
    fn sub(&mut self, a: V, b: V) -> V {
        self.binary(Op::Sub, a, b)
    }
    fn mul(&mut self, a: V, b: V) -> V {
        self.binary(Op::Mul, a, b)
    }
    fn div(&mut self, a: V, b: V) -> V {
        self.binary(Op::Div, a, b)
    }
    fn min(&mut self, a: V, b: V) -> V {
        self.binary(Op::Min, a, b)
    }
    fn max(&mut self, a: V, b: V) -> V {
        self.binary(Op::Max, a, b)
    }
    fn add_k(&mut self, a: V, k: f32) -> V {
        self.with_imm(Op::AddImm, a, k)
    }
    fn sub_k(&mut self, a: V, k: f32) -> V {
        self.with_imm(Op::SubImm, a, k)
    }
    fn rsub_k(&mut self, k: f32, a: V) -> V {
        self.with_imm(Op::RsubImm, a, k)
    }
    fn mul_k(&mut self, a: V, k: f32) -> V {
        self.with_imm(Op::MulImm, a, k)
    }
    fn div_k(&mut self, a: V, k: f32) -> V {
        self.with_imm(Op::DivImm, a, k)
    }
    fn rdiv_k(&mut self, k: f32, a: V) -> V {
        self.with_imm(Op::RdivImm, a, k)
    }
    fn min_k(&mut self, a: V, k: f32) -> V {
        self.with_imm(Op::MinImm, a, k)
    }
    fn max_k(&mut self, a: V, k: f32) -> V {
        self.with_imm(Op::MaxImm, a, k)
    }
    fn clamp_k(&mut self, a: V, lo: f32, hi: f32) -> V {
        let t = self.max_k(a, lo);
        self.min_k(t, hi)
    }
    fn neg(&mut self, a: V) -> V {
        self.unary(Op::Neg, a)
    }
    fn abs(&mut self, a: V) -> V {
        self.unary(Op::Abs, a)
    }
    fn sqrt(&mut self, a: V) -> V {
        self.unary(Op::Sqrt, a)
    }
    fn square(&mut self, a: V) -> V {
        self.unary(Op::Square, a)
    }
    fn floor(&mut self, a: V) -> V {
        self.unary(Op::Floor, a)
    }
    fn pick(&mut self, c: V, a: V, b: V) -> V {
        self.select(c, a, b)
    }
    fn k(&mut self, k: f32) -> V {
        self.konst(k)
    }
    fn length(&mut self, v: &[V]) -> V {
        match *v {
            [x] => self.abs(x),
            [x, y] => self.binary(Op::Hypot, x, y),
            [x, y, z] => self.hypot3(x, y, z),
            _ => {
                let l = self.hypot3(v[0], v[1], v[2]);
                let mut rest = vec![l];
                rest.extend_from_slice(&v[3..]);
                self.length(&rest)
            }
        }
    }
    fn dot_k(&mut self, v: V3, c: Vec3) -> V {
        let mut acc: Option<V> = None;
        for i in 0..3 {
            let term = match c[i] {
                0.0 => continue,
                1.0 => v.at(i),
                -1.0 => self.neg(v.at(i)),
                k => self.mul_k(v.at(i), k),
            };
            acc = Some(match acc {
                None => term,
                Some(a) => self.add(a, term),
            });
        }
        acc.unwrap_or_else(|| self.konst(0.0))
    }
    fn max_of(&mut self, v: &[V]) -> V {
        let mut m = v[0];
        for &x in &v[1..] {
            m = self.max(m, x);
        }
        m
    }
    fn v_sub_k(&mut self, v: V3, c: Vec3) -> V3 {
        V3(std::array::from_fn(|i| self.sub_k(v.at(i), c[i])))
    }
    fn v_add_k(&mut self, v: V3, c: Vec3) -> V3 {
        V3(std::array::from_fn(|i| self.add_k(v.at(i), c[i])))
    }
    fn v_div_k(&mut self, v: V3, c: Vec3) -> V3 {
        V3(std::array::from_fn(|i| self.div_k(v.at(i), c[i])))
    }
    fn v_abs(&mut self, v: V3) -> V3 {
        V3(std::array::from_fn(|i| self.abs(v.at(i))))
    }
    fn v_max_k(&mut self, v: V3, k: f32) -> V3 {
        V3(std::array::from_fn(|i| self.max_k(v.at(i), k)))
    }
    fn affine(&mut self, v: V3, m: &Affine3A) -> V3 {
        let cols = m.matrix3;
        V3(std::array::from_fn(|row| {
            let coefficients = Vec3::new(cols.x_axis[row], cols.y_axis[row], cols.z_axis[row]);
            let d = self.dot_k(v, coefficients);
            self.add_k(d, m.translation[row])
        }))
    }
}
