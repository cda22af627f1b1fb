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
//! the same sequence of points as alone ([`super::crossing::Confirmation`], its points
//! evaluated in the rounds with the marching lanes' of the same leaf, where one ray's secant,
//! probe and bisection points used to be evaluated one by one: a fifth of a gyroid frame), the
//! tape at a point is the point's alone ([`crate::accel::field::Cell::owns`]), and so every
//! ray's answer is the one it gets alone (tested). The packet
//! only shares the interpreter's dispatch: a tape's instruction is decoded once for the rays
//! in its leaf, which is where a single ray's march spends its time (one point per pass keeps
//! the interpreter waiting on its register file; eight keep it busy).
//!
//! A pass's lanes whose next point is in the same tape (a march step inside their part, or a
//! confirmation point in the same leaf) are evaluated again at once, without waiting for the
//! next round: a round's bookkeeping (each lane's part, the grouping by tape) is then paid when
//! a lane changes leaf rather than at every step. Waiting until at least half a pass could go
//! on, or letting lanes walk to their next part there, measured slower; the same for penumbra
//! marches measured no gain.

use super::crossing::{Candidate, Confirmation};
use super::sphere::{Along, ConvexBound, Part, Parts, Sample, hart_step, penumbra_estimate};
use super::step::{TraceResult, epsilon_at};
use crate::accel::field::{Cell, FieldCursor, ObjectField, WalkStack};
use crate::geom::Ray;
use crate::scene::TracerSettings;
use crate::sdf::simd::{PacketRegisters, SimdLevel, eval8, material8};
use crate::sdf::tape::{MATERIAL_FLOATS, MaterialVec, Registers, Tape};
use arrayvec::ArrayVec;
use glam::Vec3;

/// Rays per evaluation pass: the AVX2 lane count.
pub const PACKET: usize = 8;

/// Rays marched together at most (the lanes of a round are grouped by leaf across them):
/// four rows of a 32-pixel tile.
pub const BUNDLE: usize = 128;

// A lane's number fits the byte a round sorts it by.
const _: () = assert!(BUNDLE <= 256);

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
    /// One octree walk's frames per lane, kept across bundles.
    stacks: Vec<WalkStack>,
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
            stacks: (0..BUNDLE).map(|_| WalkStack::new()).collect(),
        }
    }

    /// `tape` at eight points ([`eval8`]).
    pub fn eval8(&mut self, tape: &Tape, xyz: &[[f32; PACKET]; 3]) -> [f32; PACKET] {
        eval8(self.level, tape, &xyz[0], &xyz[1], &xyz[2], &mut self.simd)
    }

    /// The material `tape` blends at eight points ([`crate::sdf::simd::material8`]).
    pub fn material8(
        &mut self,
        tape: &Tape,
        xyz: &[[f32; PACKET]; 3],
        materials: &[MaterialVec],
    ) -> [[f32; PACKET]; MATERIAL_FLOATS] {
        material8(
            self.level,
            tape,
            &xyz[0],
            &xyz[1],
            &xyz[2],
            materials,
            &mut self.simd,
        )
    }
}

impl Default for PacketScratch {
    fn default() -> Self {
        Self::new()
    }
}

/// One evaluation of a tape on SIMD lanes: the tape, the bundle's lanes it serves (in SIMD
/// lane order) and their points, x, y and z across the lanes.
type Pass<'t> = (&'t Tape, ArrayVec<usize, PACKET>, [[f32; PACKET]; 3]);

/// One round of a bundle: each active lane's point and the tape valid there, evaluated in
/// passes of up to [`PACKET`] lanes that share a tape.
struct Round<'t> {
    points: [Vec3; BUNDLE],
    tapes: [Option<&'t Tape>; BUNDLE],
    /// The active lanes, each with its tape's address.
    keys: ArrayVec<(usize, u8), BUNDLE>,
}

impl<'t> Round<'t> {
    fn new() -> Self {
        Round {
            points: [Vec3::ZERO; BUNDLE],
            tapes: [None; BUNDLE],
            keys: ArrayVec::new(),
        }
    }

    /// Starts a round: no lane yet.
    #[inline]
    fn begin(&mut self) {
        self.keys.clear();
    }

    /// Whether no lane is active this round.
    #[inline]
    fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// Makes the lanes of one tape adjacent, each group in lane order. A round's lanes
    /// mostly stand in a handful of leaves: a counting sort over the distinct tapes met,
    /// found by a scan of at most [`FEW_TAPES`], costs a fraction of a comparison sort of
    /// the 128 keys (5 % of a csg.ron frame); more tapes than that are sorted.
    fn group_by_tape(&mut self) {
        const FEW_TAPES: usize = 16;
        let mut tapes: ArrayVec<(usize, u8), FEW_TAPES> = ArrayVec::new();
        let mut group = [0u8; BUNDLE];
        for (k, &(tape, _)) in self.keys.iter().enumerate() {
            let g = match tapes.iter().position(|&(t, _)| t == tape) {
                Some(g) => g,
                None if tapes.is_full() => {
                    self.keys.sort_unstable();
                    return;
                }
                None => {
                    tapes.push((tape, 0));
                    tapes.len() - 1
                }
            };
            tapes[g].1 += 1;
            group[k] = g as u8;
        }
        if tapes.len() <= 1 {
            return;
        }
        // each group's first slot, then the keys placed in order (stable: lane order kept)
        let mut next = [0u8; FEW_TAPES];
        let mut at = 0u8;
        for (g, &(_, count)) in tapes.iter().enumerate() {
            next[g] = at;
            at += count;
        }
        let mut sorted = [(0usize, 0u8); BUNDLE];
        for (k, &key) in self.keys.iter().enumerate() {
            let g = group[k] as usize;
            sorted[next[g] as usize] = key;
            next[g] += 1;
        }
        let n = self.keys.len();
        self.keys.clear();
        self.keys
            .try_extend_from_slice(&sorted[..n])
            .expect("as many keys as before");
    }

    /// Lane i evaluates `tape` at `point` this round.
    #[inline]
    fn add(&mut self, i: usize, point: Vec3, tape: &'t Tape) {
        self.points[i] = point;
        self.tapes[i] = Some(tape);
        self.keys.push((std::ptr::from_ref(tape) as usize, i as u8));
    }

    /// The round's next pass, once [`Self::group_by_tape`] has made the lanes of a tape
    /// adjacent: from key `*at`, at most [`PACKET`] lanes of one tape (in key order, so in
    /// lane order), their tape and their points as SIMD lanes; `*at` moves past it. From
    /// `at = 0` until `None`, the passes are the round's; their order does not matter, each
    /// lane's value being its own. Callers loop over them rather than take them from an
    /// iterator: a pass handed out by an iterator was built in its closure's frame and
    /// copied to the loop's in wider words than it was written in, before those stores could
    /// forward (a stall on every pass).
    #[inline(always)]
    fn next_pass(&self, at: &mut usize) -> Option<Pass<'t>> {
        let tape = self.keys.get(*at)?.0;
        let mut pass = ArrayVec::new();
        while *at < self.keys.len() && self.keys[*at].0 == tape && !pass.is_full() {
            pass.push(self.keys[*at].1 as usize);
            *at += 1;
        }
        let xyz = pass_points(pass.len(), |k| self.points[pass[k]]);
        Some((self.tapes[pass[0]].expect("added"), pass, xyz))
    }
}

/// Where one lane's march stands: what every round reads. Its walk over the leaves and its
/// leaf cache, read only on leaving a part or confirming, are kept apart, so that a round
/// reads a few KiB of states rather than the 40 KiB of 128 lanes' walks.
struct State<'f> {
    part: Option<Part<'f>>,
    t: f32,
    steps: u32,
    /// A candidate hit being confirmed: the lane's next point is the confirmation's.
    confirming: Option<Confirmation>,
    done: Option<Option<f32>>,
    /// The convexity bound of a convex field, and the march's last sample for its chords.
    bound: Option<ConvexBound>,
    chord: Sample,
}

/// Hart's march of up to [`BUNDLE`] rays through one object's field; `out[i]` is what
/// [`super::sphere::trace_hart`] returns for `lanes[i]` alone. A lane confirming a candidate
/// hit ([`Confirmation`]) stays in the rounds, its points evaluated with the
/// others' of the leaf they fall in, rather than on its own.
pub fn trace_hart_packet(
    field: &ObjectField,
    lanes: &[Lane],
    s: &TracerSettings,
    scratch: &mut PacketScratch,
    out: &mut [TraceResult],
) {
    assert!(lanes.len() <= BUNDLE && out.len() == lanes.len());
    let PacketScratch {
        simd,
        regs,
        level,
        stacks,
    } = scratch;
    let mut cursor = field.cursor(regs);
    let mut states: Vec<State> = lanes
        .iter()
        .map(|l| State {
            part: None,
            t: l.t0,
            steps: 0,
            confirming: None,
            done: None,
            bound: field
                .convex
                .map(|model| ConvexBound::new(model, &l.ray, l.t0, l.t1)),
            chord: Sample::NONE,
        })
        .collect();
    let mut walks: Vec<Parts> = lanes
        .iter()
        .zip(stacks.iter_mut())
        .map(|(l, stack)| Parts::new(&cursor, &l.ray, l.t0, l.t1, stack))
        .collect();
    // The leaf each lane last looked a confirmation's point up in, unless a short whole tape
    // has the same value everywhere.
    let short = cursor.short_whole_tape();
    let mut cells: Vec<Option<Cell>> = vec![None; lanes.len()];
    let mut round = Round::new();
    loop {
        round.begin();
        for (i, st) in states.iter_mut().enumerate() {
            if st.done.is_some() {
                continue;
            }
            if let Some(c) = &st.confirming {
                let (p, tape) = confirmation_point(&lanes[i], c, short, &mut cursor, &mut cells[i]);
                round.add(i, p, tape);
                continue;
            }
            find_part(st, &lanes[i], &mut walks[i]);
            if st.done.is_none() {
                if st.steps >= s.max_steps {
                    st.done = Some(None);
                } else {
                    let part = st.part.expect("a lane not done has a part");
                    round.add(i, lanes[i].ray.at(st.t), part.tape);
                }
            }
        }
        if round.is_empty() {
            break;
        }
        round.group_by_tape();
        let mut at = 0;
        while let Some((tape, mut pass, mut xyz)) = round.next_pass(&mut at) {
            loop {
                let d = eval8(*level, tape, &xyz[0], &xyz[1], &xyz[2], simd);
                for (k, &i) in pass.iter().enumerate() {
                    march_step(&mut states[i], &lanes[i], d[k], s);
                }
                // The lanes whose next point is in the same tape step again at once, where
                // the next round would add them (finding the next part is left to it).
                let mut points = [Vec3::ZERO; PACKET];
                let mut kept = 0;
                for j in 0..pass.len() {
                    let i = pass[j];
                    let st = &states[i];
                    let next = if st.done.is_some() {
                        None
                    } else if let Some(c) = &st.confirming {
                        let (p, there) =
                            confirmation_point(&lanes[i], c, short, &mut cursor, &mut cells[i]);
                        std::ptr::eq(there, tape).then_some(p)
                    } else {
                        let in_part = st
                            .part
                            .is_some_and(|p| st.t <= p.end && std::ptr::eq(p.tape, tape));
                        (in_part && st.steps < s.max_steps).then(|| lanes[i].ray.at(st.t))
                    };
                    if let Some(p) = next {
                        pass[kept] = i;
                        points[kept] = p;
                        kept += 1;
                    }
                }
                if kept == 0 {
                    break;
                }
                pass.truncate(kept);
                xyz = pass_points(pass.len(), |k| points[k]);
            }
        }
    }
    for (o, st) in out.iter_mut().zip(&states) {
        *o = TraceResult::of_points(st.done.flatten(), st.steps);
    }
}

/// Moves a marching lane to the part that holds its t (the next one once past it); none
/// left ends its march.
#[inline]
fn find_part<'f>(st: &mut State<'f>, lane: &Lane, walk: &mut Parts<'f, '_>) {
    loop {
        match st.part {
            Some(p) if st.t <= p.end => return,
            Some(_) if st.t > lane.t1 => {
                st.done = Some(None);
                return;
            }
            _ => match walk.next(st.t) {
                Some(p) => {
                    st.t = p.start;
                    st.part = Some(p);
                }
                None => {
                    st.done = Some(None);
                    return;
                }
            },
        }
    }
}

/// A confirming lane's next point and the tape there: that of the leaf holding it (a short
/// whole tape has the same value there).
#[inline]
fn confirmation_point<'f>(
    lane: &Lane,
    c: &Confirmation,
    short: Option<&'f Tape>,
    cursor: &mut FieldCursor<'f, '_>,
    cell: &mut Option<Cell<'f>>,
) -> (Vec3, &'f Tape) {
    let p = lane.ray.at(c.at());
    let tape = match short {
        Some(whole) => whole,
        None => cursor.region_cached(p, cell).tape,
    };
    (p, tape)
}

/// A pass's points as SIMD lanes, the point of lane `k` of the pass given by `point(k)`;
/// spare lanes repeat the first point, unused.
#[inline]
fn pass_points(len: usize, point: impl Fn(usize) -> Vec3) -> [[f32; PACKET]; 3] {
    let points: [Vec3; PACKET] = std::array::from_fn(|k| point(k.min(len - 1)));
    [
        points.map(|p| p.x),
        points.map(|p| p.y),
        points.map(|p| p.z),
    ]
}

/// One lane's step from the field value `d` at its point: the next point of a confirmation,
/// a hit confirmed or refuted, a miss the convexity bound settles, or Hart's step.
#[inline]
fn march_step(st: &mut State, lane: &Lane, d: f32, s: &TracerSettings) {
    st.steps += 1;
    let decided = match &mut st.confirming {
        Some(c) => c.feed_in(d, lane.t1, s),
        None => {
            let t = st.t;
            let eps = epsilon_at(s, t);
            if d >= eps {
                if st.bound.is_some_and(|b| b.stays_off(st.chord, t, d, s)) {
                    st.done = Some(None);
                    return;
                }
                st.chord = Sample { t, h: d };
                let part = st.part.expect("active");
                st.t = t + hart_step(d, &part, t, eps);
                return;
            }
            st.chord = Sample::NONE;
            Confirmation::start_in(&mut st.confirming, t, d, lane.t1, s)
        }
    };
    match decided {
        // confirming: the lane's next point is the confirmation's
        None => {}
        Some(Candidate::Hit(t)) => {
            st.confirming = None;
            st.done = Some(Some(t));
        }
        Some(Candidate::Continue(next)) => {
            st.confirming = None;
            st.t = next;
        }
    }
}

/// Where one lane's penumbra march stands (its walk over the leaves kept apart, as
/// [`State`]'s).
struct Shadowed {
    res: f32,
    previous: Sample,
    t: f32,
    samples: u32,
    done: bool,
    bound: Option<ConvexBound>,
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
    let PacketScratch {
        simd,
        regs,
        level,
        stacks,
    } = scratch;
    let cursor = field.cursor(regs);
    let mut walks: Vec<Along> = lanes
        .iter()
        .zip(stacks.iter_mut())
        .map(|(l, stack)| Along::for_penumbra(&cursor, &l.ray, l.t0, l.t1, stack))
        .collect();
    let mut states: Vec<Shadowed> = lanes
        .iter()
        .map(|l| Shadowed {
            res: 1.0,
            previous: Sample::NONE,
            t: l.t0,
            samples: 0,
            done: s.max_steps == 0,
            bound: field
                .convex
                .map(|model| ConvexBound::new(model, &l.ray, l.t0, l.t1)),
        })
        .collect();
    let mut round = Round::new();
    loop {
        round.begin();
        for (i, st) in states.iter_mut().enumerate() {
            if !st.done {
                round.add(i, lanes[i].ray.at(st.t), walks[i].tape(st.t));
            }
        }
        if round.is_empty() {
            break;
        }
        round.group_by_tape();
        let mut at = 0;
        while let Some((tape, pass, xyz)) = round.next_pass(&mut at) {
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
                    .min(penumbra_estimate(h[j], st.previous.h, t, k, improved));
                if st
                    .bound
                    .is_some_and(|b| b.settles(st.previous, t, h[j], st.res, k, s))
                {
                    st.done = true;
                    continue;
                }
                st.previous = Sample { t, h: h[j] };
                st.t = t + h[j];
                if st.t > lanes[i].t1 || st.res < 1e-4 || st.samples >= s.max_steps {
                    st.done = true;
                }
            }
        }
    }
    for (o, st) in out.iter_mut().zip(&states) {
        *o = st.res.clamp(0.0, 1.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A round's passes for lanes standing in `leaf_of[i]`'s tape: each pass one tape's lanes,
    /// in lane order, at most [`PACKET`] of them; every lane in exactly one pass.
    fn check_passes(leaf_of: &[usize], tapes: &[Tape]) {
        let mut round = Round::new();
        round.begin();
        for (i, &leaf) in leaf_of.iter().enumerate() {
            round.add(i, Vec3::splat(i as f32), &tapes[leaf]);
        }
        let mut seen = vec![false; leaf_of.len()];
        let mut passes_of_tape: Vec<Vec<usize>> = vec![Vec::new(); tapes.len()];
        let mut passes = 0;
        round.group_by_tape();
        let mut at = 0;
        while let Some((tape, pass, xyz)) = round.next_pass(&mut at) {
            passes += 1;
            let t = tapes
                .iter()
                .position(|x| std::ptr::eq(x, tape))
                .expect("one of the tapes");
            assert!(!pass.is_empty() && pass.len() <= PACKET);
            for (k, &i) in pass.iter().enumerate() {
                assert_eq!(leaf_of[i], t, "lane {i} in a pass of another tape");
                assert!(!seen[i], "lane {i} twice");
                seen[i] = true;
                assert_eq!(xyz[0][k], i as f32, "lane {i}'s point");
                passes_of_tape[t].push(i);
            }
        }
        assert!(seen.iter().all(|&s| s), "every lane evaluated");
        // grouped: a tape's lanes fill whole passes but its last
        let fewest: usize = passes_of_tape
            .iter()
            .map(|lanes| lanes.len().div_ceil(PACKET))
            .sum();
        assert_eq!(passes, fewest, "lanes of one tape split across passes");
        for lanes in passes_of_tape {
            assert!(
                lanes.windows(2).all(|w| w[0] < w[1]),
                "lane order: {lanes:?}"
            );
        }
    }

    #[test]
    fn a_round_groups_its_lanes_by_tape_in_lane_order() {
        let tapes: Vec<Tape> = (0..40).map(|_| Tape::default()).collect();
        // one tape; a few, interleaved; more than the counting sort takes (sorted instead)
        let one = vec![3; BUNDLE];
        let few: Vec<usize> = (0..BUNDLE).map(|i| (i * 7) % 5).collect();
        let many: Vec<usize> = (0..BUNDLE).map(|i| (i * 13) % 40).collect();
        let ragged: Vec<usize> = (0..37).map(|i| [0, 0, 9, 2, 9, 9][i % 6]).collect();
        for leaf_of in [one, few, many, ragged] {
            check_passes(&leaf_of, &tapes);
        }
    }
}
