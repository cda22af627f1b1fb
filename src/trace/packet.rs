//! Coherent rays marched together: a bundle of up to [`BUNDLE`] rays of a tile's band of rows
//! sphere-traced through one object at once, round by round, the samples of the rays that
//! stand in the same leaf evaluated together, eight per pass of that leaf's tape on SIMD
//! lanes ([`crate::sdf::simd`]). Neighbouring rows share leaves as much as neighbouring
//! pixels of a row do: over the small leaves of a large union, eight rays of one row stood in
//! 1.6 leaves on average, so most passes filled a lane or two.
//!
//! Each ray keeps its own march — its parts ([`super::sphere`]'s leaves and whole-tape
//! stretches), its t, its step count — and takes exactly the steps [`super::sphere::trace_hart`]
//! takes alone: the lanes give the scalar interpreter's bits, a candidate hit is confirmed by
//! the scalar code, and so every ray's answer is the one it gets alone (tested). The packet
//! only shares the interpreter's dispatch: a tape's instruction is decoded once for the rays
//! in its leaf, which is where a single ray's march spends its time (one point per pass keeps
//! the interpreter waiting on its register file; eight keep it busy).

use super::crossing::{self, Candidate};
use super::sphere::{Along, Part, Parts, hart_step, penumbra_estimate};
use super::step::{TraceResult, epsilon_at};
use crate::accel::field::ObjectField;
use crate::geom::Ray;
use crate::scene::TracerSettings;
use crate::sdf::simd::{PacketRegisters, SimdLevel, eval8};
use crate::sdf::tape::{Registers, Tape};
use arrayvec::ArrayVec;

/// Rays per evaluation pass: the AVX2 lane count.
pub const PACKET: usize = 8;

/// Rays marched together at most (the lanes of a round are grouped by leaf across them):
/// four rows of a 32-pixel tile.
pub const BUNDLE: usize = 128;

/// A set of a bundle's lanes.
type Lanes = u128;
const _: () = assert!(BUNDLE <= Lanes::BITS as usize);

/// The lanes of `set`, lowest first.
fn members(mut set: Lanes) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (set != 0).then(|| {
            let i = set.trailing_zeros() as usize;
            set &= set - 1;
            i
        })
    })
}

/// One ray of a packet: what it marches over, and its answer when done.
#[derive(Debug, Clone, Copy)]
pub struct Lane {
    /// The ray.
    pub ray: Ray,
    /// Start of its interval.
    pub t0: f32,
    /// End of its interval.
    pub t1: f32,
}

/// Scratch reused across packets.
pub struct PacketScratch {
    simd: PacketRegisters,
    regs: Registers,
    level: SimdLevel,
}

impl PacketScratch {
    /// Scratch for the SIMD level this CPU runs.
    pub fn new() -> Self {
        Self::with_level(SimdLevel::detect())
    }

    /// Scratch for a given level (tests compare them).
    pub fn with_level(level: SimdLevel) -> Self {
        PacketScratch {
            simd: PacketRegisters::new(),
            regs: Registers::new(),
            level,
        }
    }
}

impl Default for PacketScratch {
    fn default() -> Self {
        Self::new()
    }
}

/// The lanes of `active` that share the lowest one's tape (taken out of `active`), and that
/// tape.
#[inline]
fn next_group<'t>(active: &mut Lanes, tape_of: impl Fn(usize) -> &'t Tape) -> (&'t Tape, Lanes) {
    let tape = tape_of(active.trailing_zeros() as usize);
    let group = members(*active)
        .filter(|&i| std::ptr::eq(tape_of(i), tape))
        .fold(0 as Lanes, |g, i| g | 1 << i);
    *active &= !group;
    (tape, group)
}

/// The next pass of up to [`PACKET`] lanes of `rest` (taken out of it), lowest first, with
/// their points (`point` of each lane) on SIMD lanes; spare SIMD lanes repeat the pass's first
/// point, unused.
#[inline]
fn next_pass(
    rest: &mut Lanes,
    point: impl Fn(usize) -> glam::Vec3,
) -> Option<(ArrayVec<usize, PACKET>, [[f32; PACKET]; 3])> {
    if *rest == 0 {
        return None;
    }
    let pass: ArrayVec<usize, PACKET> = members(*rest).take(PACKET).collect();
    for &i in &pass {
        *rest &= !(1 << i);
    }
    let mut xyz = [[0.0f32; PACKET]; 3];
    for k in 0..PACKET {
        let p = point(pass[k.min(pass.len() - 1)]);
        for a in 0..3 {
            xyz[a][k] = p[a];
        }
    }
    Some((pass, xyz))
}

/// Where one lane's march stands.
struct State<'f> {
    parts: Parts<'f>,
    part: Option<Part<'f>>,
    t: f32,
    steps: u32,
    done: Option<Option<f32>>,
}

/// Hart's march of up to [`BUNDLE`] rays through one object's field; `out[i]` is what
/// [`super::sphere::trace_hart`] returns for `lanes[i]` alone.
pub fn trace_hart_packet(
    field: &ObjectField,
    lanes: &[Lane],
    s: &TracerSettings,
    scratch: &mut PacketScratch,
    out: &mut [TraceResult],
) {
    assert!(lanes.len() <= BUNDLE && out.len() == lanes.len());
    let PacketScratch { simd, regs, level } = scratch;
    let mut states: Vec<State> = {
        let cursor = field.cursor(regs);
        lanes
            .iter()
            .map(|l| State {
                parts: Parts::new(&cursor, &l.ray, l.t0, l.t1),
                part: None,
                t: l.t0,
                steps: 0,
                done: None,
            })
            .collect()
    };
    loop {
        // Every unfinished lane at the part that holds its t (the next one once past it).
        let mut active: Lanes = 0;
        for (i, st) in states.iter_mut().enumerate() {
            if st.done.is_some() {
                continue;
            }
            loop {
                match st.part {
                    Some(p) if st.t <= p.end => break,
                    Some(_) if st.t > lanes[i].t1 => {
                        st.done = Some(None);
                        break;
                    }
                    _ => match st.parts.next(st.t) {
                        Some(p) => {
                            st.t = p.start;
                            st.part = Some(p);
                        }
                        None => {
                            st.done = Some(None);
                            break;
                        }
                    },
                }
            }
            if st.done.is_none() {
                if st.steps >= s.max_steps {
                    st.done = Some(None);
                } else {
                    active |= 1 << i;
                }
            }
        }
        if active == 0 {
            break;
        }
        // The active lanes by tape (lanes in one leaf share it), eight per pass.
        while active != 0 {
            let (tape, mut rest) = next_group(&mut active, |i| {
                states[i].part.expect("an active lane has a part").tape
            });
            while let Some((pass, xyz)) = next_pass(&mut rest, |i| lanes[i].ray.at(states[i].t)) {
                let d = eval8(*level, tape, &xyz[0], &xyz[1], &xyz[2], simd);
                for (k, &i) in pass.iter().enumerate() {
                    march_step(field, &mut states[i], &lanes[i], d[k], s, regs);
                }
            }
        }
    }
    for (o, st) in out.iter_mut().zip(&states) {
        *o = TraceResult::of_points(st.done.flatten(), st.steps);
    }
}

/// One lane's step from the field value `d` at its t: a hit confirmed or refuted, or Hart's
/// step.
#[inline]
fn march_step(
    field: &ObjectField,
    st: &mut State,
    lane: &Lane,
    d: f32,
    s: &TracerSettings,
    regs: &mut Registers,
) {
    st.steps += 1;
    let part = st.part.expect("active");
    let (ray, t) = (&lane.ray, st.t);
    let eps = epsilon_at(s, t);
    if d < eps {
        let mut cursor = field.cursor(regs);
        match crossing::confirm(&mut cursor, ray, t, d, lane.t1, s, &mut st.steps) {
            Candidate::Hit(t) => st.done = Some(Some(t)),
            Candidate::Continue(next) => st.t = next,
        }
    } else {
        st.t = t + hart_step(d, &part, t, eps);
    }
}

/// Where one lane's penumbra march stands.
struct Shadowed<'f> {
    along: Along<'f>,
    res: f32,
    previous: f32,
    t: f32,
    samples: u32,
    done: bool,
}

/// Quilez's penumbra ([`super::sphere::penumbra`]) of up to [`BUNDLE`] shadow rays through
/// one object, sampled where each ray alone samples it; `out[i]` is what the scalar march
/// returns for `lanes[i]`.
#[allow(clippy::too_many_arguments)]
pub fn penumbra_packet(
    field: &ObjectField,
    lanes: &[Lane],
    s: &TracerSettings,
    k: f32,
    improved: bool,
    scratch: &mut PacketScratch,
    out: &mut [f32],
) {
    assert!(lanes.len() <= BUNDLE && out.len() == lanes.len());
    let PacketScratch { simd, regs, level } = scratch;
    let mut states: Vec<Shadowed> = {
        let cursor = field.cursor(regs);
        lanes
            .iter()
            .map(|l| Shadowed {
                along: Along::new(&cursor, &l.ray, l.t0, l.t1),
                res: 1.0,
                previous: f32::INFINITY,
                t: l.t0,
                samples: 0,
                done: s.max_steps == 0,
            })
            .collect()
    };
    let mut tapes: Vec<Option<&Tape>> = vec![None; lanes.len()];
    loop {
        let mut active: Lanes = 0;
        for (i, st) in states.iter_mut().enumerate() {
            if !st.done {
                tapes[i] = Some(st.along.tape(st.t));
                active |= 1 << i;
            }
        }
        if active == 0 {
            break;
        }
        // The active lanes by tape, eight per pass.
        while active != 0 {
            let (tape, mut rest) = next_group(&mut active, |i| tapes[i].expect("active"));
            while let Some((pass, xyz)) = next_pass(&mut rest, |i| lanes[i].ray.at(states[i].t)) {
                let h = eval8(*level, tape, &xyz[0], &xyz[1], &xyz[2], simd);
                for (j, &i) in pass.iter().enumerate() {
                    let st = &mut states[i];
                    let t = st.t;
                    st.samples += 1;
                    if h[j] < epsilon_at(s, t) {
                        st.res = 0.0;
                        st.done = true;
                        continue;
                    }
                    st.res = st
                        .res
                        .min(penumbra_estimate(h[j], st.previous, t, k, improved));
                    st.previous = h[j];
                    st.t = t + h[j];
                    if st.t > lanes[i].t1 || st.res < 1e-4 || st.samples >= s.max_steps {
                        st.done = true;
                    }
                }
            }
        }
    }
    for (o, st) in out.iter_mut().zip(&states) {
        *o = st.res.clamp(0.0, 1.0);
    }
}
