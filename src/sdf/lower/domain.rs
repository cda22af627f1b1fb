//! Domain operators — repetition, twist and bend — and the Lipschitz clip that keeps a
//! steeper field safe to sphere-trace.

use super::emit::{Emit, V3};
use super::shapes::{self, Out};
use super::{Context, LowerError, fmt3};
use crate::sdf::node::SdfNode;
use crate::sdf::ssa::{Builder, V};
use crate::sdf::tape::Op;
use glam::Vec3;

/// Clips a λ-Lipschitz field to a convex region R and makes it 1-Lipschitz everywhere:
/// g(p) = max(f(π(p))/λ, d_R(p)), with π the projection onto R (evaluated by the caller, who
/// passes f(π(p)) as `f_projected`) and d_R the exact signed distance to R.
/// π is non-expanding and f/λ is 1-Lipschitz on R, so f∘π/λ is 1-Lipschitz on all of space,
/// and so is the max of two 1-Lipschitz functions. Inside R, g = max(f/λ, d_R) is the surface
/// clipped to R; outside, g stays ≥ f(π(p))/λ > 0 wherever the clipped surface is absent, so the
/// region's own boundary never looks like a surface.
pub fn clip_lipschitz(b: &mut Builder, f_projected: V, lambda: f32, region_distance: V) -> V {
    let scaled = b.mul_k(f_projected, 1.0 / lambda);
    b.max(scaled, region_distance)
}

/// (u, v) turned by the angle `ang`: (u·cos − v·sin, v·cos + u·sin).
fn rotate(b: &mut Builder, ang: V, u: V, v: V) -> (V, V) {
    let (cs, sn) = (b.unary(Op::Cos, ang), b.unary(Op::Sin, ang));
    let vs = b.mul(sn, v);
    let uc = b.mul(cs, u);
    let u2 = b.sub(uc, vs);
    let us = b.mul(sn, u);
    let vc = b.mul(cs, v);
    (u2, b.add(vc, us))
}

/// Projection of p onto the box [−h, h].
pub fn project_box(b: &mut Builder, p: V3, h: Vec3) -> V3 {
    V3(std::array::from_fn(|i| b.clamp_k(p.at(i), -h[i], h[i])))
}

/// Projection of p onto the cylinder about y of radius r and |y| ≤ h.
fn project_cylinder_y(b: &mut Builder, p: V3, h: f32, r: f32) -> V3 {
    let l = b.length(&[p.x(), p.z()]);
    let l = b.max_k(l, 1e-30);
    let s = b.rdiv_k(r, l);
    let s = b.min_k(s, 1.0);
    let x = b.mul(p.x(), s);
    let z = b.mul(p.z(), s);
    let y = b.clamp_k(p.y(), -h, h);
    V3([x, y, z])
}

impl Context<'_> {
    /// Domain repetition (Quilez, "domain repetition", 2023 revision): the child is evaluated
    /// in its own cell *and* in the neighbouring cell on the near side of every repeated axis
    /// (2^k cells for k repeated axes), and the minimum is taken; every copy outside that block
    /// lies beyond the own cell's far wall, at least c/2 + |q| + gap away (gap = clearance
    /// between the child's bounds and its cell wall), which caps the result. The cap never
    /// falls below c/2, so empty cell walls never look like surfaces. The distance to the slab
    /// (or box) holding all copies is a second lower bound for the far copies, which lets rays
    /// far from the pattern take long steps. Bound; λ = 1.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn repeat(
        &mut self,
        b: &mut Builder,
        node: &SdfNode,
        shape: &SdfNode,
        p: V3,
        mat: u32,
        c: Vec3,
        limit: Option<Vec3>,
    ) -> Result<Out, LowerError> {
        const FAR: f32 = 1e30;
        let child = self.bounds(shape)?;
        let half = 0.5 * c;
        let mut gap = f32::INFINITY;
        for i in 0..3 {
            if c[i] > 0.0 {
                let g = (half[i] - child.max[i]).min(child.min[i] + half[i]);
                if g.is_nan() || g < 0.0 {
                    return Err(self.field_error(
                        "period",
                        format!(
                            "the shape (bounds {}..{}) does not fit in its cell of period {} on \
                             axis {}: copies would overlap; use a larger period",
                            fmt3(child.min),
                            fmt3(child.max),
                            c[i],
                            ["x", "y", "z"][i]
                        ),
                    ));
                }
                gap = gap.min(g);
            }
        }
        let axes: Vec<usize> = (0..3).filter(|&i| c[i] > 0.0).collect();
        // Per repeated axis: own cell ⌊p/c + ½⌋ (⌊x + ½⌋ rather than round(): WGSL rounds
        // halves to even), the offset q in it, the sign s of q (0 at the exact centre, where
        // the own cell suffices) and the step to the near neighbour.
        let mut cell = [p.x(); 3];
        let mut q = p;
        let mut sign = [p.x(); 3];
        let mut step = [p.x(); 3];
        for &i in &axes {
            let t = b.mul_k(p.at(i), 1.0 / c[i]);
            let t = b.add_k(t, 0.5);
            let mut ci = b.floor(t);
            if let Some(n) = limit {
                ci = b.clamp_k(ci, -n[i], n[i]);
            }
            let off = b.mul_k(ci, c[i]);
            let qi = b.sub(p.at(i), off);
            let aq = b.abs(qi);
            let aq_safe = b.max_k(aq, 1e-30);
            let si = b.div(qi, aq_safe);
            let mut near = b.add(ci, si);
            if let Some(n) = limit {
                near = b.clamp_k(near, -n[i], n[i]);
            }
            cell[i] = ci;
            q.0[i] = qi;
            sign[i] = si;
            step[i] = b.sub(near, ci);
        }
        let mut acc: Option<Out> = None;
        for mask in 0..(1u32 << axes.len()) {
            let mut qm = q;
            for (k, &i) in axes.iter().enumerate() {
                if mask & (1 << k) != 0 {
                    let cm = b.add(cell[i], step[i]);
                    let off = b.mul_k(cm, c[i]);
                    qm.0[i] = b.sub(p.at(i), off);
                }
            }
            let out = self.child(b, "shape", shape, qm, mat)?;
            acc = Some(match acc {
                None => out,
                Some(a) => shapes::union(b, a, out),
            });
        }
        let block = acc.expect("at least one cell");
        // distance to the own cell's far wall, pushed out of reach where no copy lies beyond
        let mut wall: Option<V> = None;
        for &i in &axes {
            let aq = b.abs(q.at(i));
            let mut far_wall = b.add_k(aq, half[i]);
            if let Some(n) = limit {
                let beyond = b.sub(cell[i], sign[i]);
                let beyond = b.abs(beyond);
                let missing = b.sub_k(beyond, n[i]);
                let missing = b.clamp_k(missing, 0.0, 1.0);
                let far = b.mul_k(missing, FAR);
                far_wall = b.add(far, far_wall);
            }
            wall = Some(match wall {
                None => far_wall,
                Some(w) => b.min(w, far_wall),
            });
        }
        let wall = wall.expect("at least one repeated axis");
        let mut cap = b.add_k(wall, gap);
        // the region holding every copy: a box over its finite axes (a slab or a column)
        let region = self.bounds(node)?;
        let finite: Vec<usize> = (0..3)
            .filter(|&i| region.min[i].is_finite() && region.max[i].is_finite())
            .collect();
        if !finite.is_empty() {
            let centre = region.center();
            let extent = 0.5 * (region.max - region.min);
            let offsets: Vec<V> = finite
                .iter()
                .map(|&i| {
                    let l = b.sub_k(p.at(i), centre[i]);
                    let a = b.abs(l);
                    b.sub_k(a, extent[i])
                })
                .collect();
            let positive: Vec<V> = offsets.iter().map(|&o| b.max_k(o, 0.0)).collect();
            let outside = b.length(&positive);
            let m = b.max_of(&offsets);
            let inside = b.min_k(m, 0.0);
            let slab = b.add(outside, inside);
            cap = b.max(cap, slab);
        }
        Ok(Out {
            d: b.min(block.d, cap),
            m: block.m,
        })
    }

    /// Twist about y at `k` radians per unit, evaluated at the projection onto the bounding
    /// cylinder and clipped to it (see [`clip_lipschitz`]).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn twist(
        &mut self,
        b: &mut Builder,
        node: &SdfNode,
        shape: &SdfNode,
        p: V3,
        mat: u32,
        k: f32,
    ) -> Result<Out, LowerError> {
        let cb = self.bounds(shape)?;
        let region = self.bounds(node)?;
        let r = region.max.x;
        // J = [R_xz | k·r·u + e_y]: singular values of [[1, kr],[kr, 1+k²r²]]^½ give
        // σ_max = (k r + √(4 + k² r²)) / 2 (≤ 1 + k r).
        let kr = k.abs() * r;
        let lambda = 0.5 * (kr + (4.0 + kr * kr).sqrt());
        let center = Vec3::new(0.0, 0.5 * (cb.min.y + cb.max.y), 0.0);
        let half_h = 0.5 * (cb.max.y - cb.min.y);
        let local = b.v_sub_k(p, center);
        let region_d = shapes::cylinder_y(b, local, half_h, r);
        let proj = project_cylinder_y(b, local, half_h, r);
        let pp = b.v_add_k(proj, center);
        let ang = b.mul_k(pp.y(), k);
        let (qx, qz) = rotate(b, ang, pp.x(), pp.z());
        let q = V3([qx, pp.y(), qz]);
        let out = self.child(b, "shape", shape, q, mat)?;
        Ok(Out {
            d: clip_lipschitz(b, out.d, lambda, region_d),
            m: out.m,
        })
    }

    /// Bend about z at `k` radians per unit along x, evaluated at the projection onto the
    /// bounding cylinder about z and clipped to it.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn bend(
        &mut self,
        b: &mut Builder,
        node: &SdfNode,
        shape: &SdfNode,
        p: V3,
        mat: u32,
        k: f32,
    ) -> Result<Out, LowerError> {
        let cb = self.bounds(shape)?;
        let region = self.bounds(node)?;
        let r = region.max.x;
        // J = R(kx)·(I + k·w·e_xᵀ) with |w| = r: ‖J‖ ≤ 1 + k r (triangle inequality).
        let lambda = 1.0 + k.abs() * r;
        let center = Vec3::new(0.0, 0.0, 0.5 * (cb.min.z + cb.max.z));
        let half_h = 0.5 * (cb.max.z - cb.min.z);
        let local = b.v_sub_k(p, center);
        // the cylinder about z is the cylinder about y with y and z exchanged
        let swapped = V3([local.x(), local.z(), local.y()]);
        let region_d = shapes::cylinder_y(b, swapped, half_h, r);
        let proj = project_cylinder_y(b, swapped, half_h, r);
        let proj = V3([proj.x(), proj.z(), proj.y()]);
        let pp = b.v_add_k(proj, center);
        let x = pp.x();
        let ang = b.mul_k(x, k);
        let (qx, qy) = rotate(b, ang, x, pp.y());
        let q = V3([qx, qy, pp.z()]);
        let out = self.child(b, "shape", shape, q, mat)?;
        Ok(Out {
            d: clip_lipschitz(b, out.d, lambda, region_d),
            m: out.m,
        })
    }
}
