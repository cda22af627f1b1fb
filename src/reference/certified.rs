//! Certified ray–SDF intersection: the first root of f(o + t·d) on a ray interval by interval
//! bisection over the tape's f64 enclosures, and certified bounds of f along a ray.
//!
//! The method is Mitchell's (1990, "Robust ray intersection with interval arithmetic", §3)
//! and Snyder's (1992, "Interval analysis for computer graphics", §4.2): the enclosure of f
//! over the box a stretch [a, b] of the ray sweeps ([`Program::eval`], inclusion property)
//! either excludes 0 — no root there, the stretch is dropped — or the stretch is halved, the
//! front half first, so the first stretch found of width ≤ δ on which f is certified to change
//! sign encloses the first crossing. Each stretch's program is pruned to the box (a union's
//! far-away members drop out), which keeps a 400-member union cheap near any one member.
//!
//! A stretch of width ≤ δ whose enclosure holds 0 but whose far end is not certified past the
//! surface is a *touch*: the ray comes within the enclosure's width of the surface there, and
//! may cross and come back within δ (a sliver thinner than δ), which no finite search can rule
//! out. Touches are counted in [`Crossing::touched`]; the search goes on past them.
//!
//! Where the lowering guarantees the field's Lipschitz bound L ([`Search::lipschitz`]), a
//! stretch whose midpoint enclosure exceeds L times half its length is dropped too: the field
//! cannot reach 0 on it. This settles rays that skim a surface at a small distance along a long
//! stretch, where the enclosure of each sweep box stays loose (the boxes are as wide as the
//! stretch in every axis, and a smooth blend of shells multiplies the overestimate) and
//! bisection alone needs tens of thousands of boxes.
//!
//! Work per ray is bounded ([`Search::max_boxes`]): a search that needs more boxes is reported
//! [`Root::Uncertified`], never guessed.

use super::interval64::{Interval, Program, Registers};
use crate::sdf::interval::Domain;
use glam::DVec3;

/// How a certified search is bounded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Search {
    /// Width δ of the stretch a root is enclosed in (world units along a unit ray).
    pub delta: f64,
    /// Most boxes (interval evaluations) one search may take.
    pub max_boxes: u32,
    /// A bound on |f(p) − f(q)| / |p − q| the lowering guarantees (1 for every node but
    /// implicit surfaces, whose λ is estimated), or `None` to rely on enclosures alone.
    pub lipschitz: Option<f64>,
}

/// The certified search for a scene traced with `settings`: roots enclosed within δ = ε₀/64
/// (ε₀ the tracer's hit threshold at t = 0, so δ is far below every |Δt| tolerance, which
/// starts at 10·ε), at most [`MAX_BOXES`] interval evaluations per ray and object.
pub fn certified_search(settings: &crate::scene::TracerSettings) -> Search {
    Search {
        delta: settings.epsilon as f64 / 64.0,
        max_boxes: MAX_BOXES,
        lipschitz: Some(1.0),
    }
}

/// The work bound of [`certified_search`]: a bisection to δ takes about log₂(length/δ) ≈ 30
/// levels with a few boxes alive per level near a surface; the bound leaves room for
/// stretches where the enclosure is loose (a smooth blend of many members).
pub const MAX_BOXES: u32 = 20_000;

impl Search {
    /// How far f may move from its value at the middle of the stretch [a, b] of a ray along
    /// `d`: L·|d|·(b − a)/2, where the Lipschitz bound L is known.
    fn reach(&self, d: DVec3, a: f64, b: f64) -> Option<f64> {
        self.lipschitz.map(|l| l * d.length() * 0.5 * (b - a))
    }
}

/// The first crossing found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Crossing {
    /// The stretch [lo, hi], hi − lo ≤ δ, in which f takes the start's sign at lo's side and
    /// the other (or 0) at hi.
    pub lo: f64,
    /// See `lo`.
    pub hi: f64,
    /// Touches met before it (see the module documentation).
    pub touched: u32,
}

/// The outcome of a certified root search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Root {
    /// f changes sign, first within this stretch.
    Crossing(Crossing),
    /// No crossing on the interval (up to touches: stretches of width ≤ δ where the ray comes
    /// within the enclosure's width of the surface), certified.
    None {
        /// Touches met.
        touched: u32,
    },
    /// The search ran out of boxes.
    Uncertified,
}

/// The box the ray's points o + t·d, t ∈ [a, b], lie in, rounded outward.
fn sweep(o: DVec3, d: DVec3, a: f64, b: f64) -> [Interval; 3] {
    let t = Interval::new(a, b);
    [0, 1, 2].map(|k| Interval::point(o[k]).add(t.mul(Interval::point(d[k]))))
}

/// An enclosure of f at the ray's point for t (the point itself rounded outward).
pub fn at(program: &Program, o: DVec3, d: DVec3, t: f64, regs: &mut Registers) -> Interval {
    let [x, y, z] = sweep(o, d, t, t);
    program.eval(x, y, z, regs)
}

/// Programs pruned to the stretches of one search, stretches indexing into it.
struct Arena<'p> {
    root: &'p Program,
    pruned: Vec<Program>,
}

impl Arena<'_> {
    fn get(&self, k: usize) -> &Program {
        if k == 0 {
            self.root
        } else {
            &self.pruned[k - 1]
        }
    }

    /// The enclosure of f over the stretch's box, and the program index its halves use.
    fn eval(&mut self, k: usize, b: [Interval; 3], regs: &mut Registers) -> (Interval, usize) {
        let (v, pruned) = self.get(k).prune(b[0], b[1], b[2], regs);
        match pruned {
            Some(p) if p.len() < self.get(k).len() => {
                self.pruned.push(p);
                (v, self.pruned.len())
            }
            _ => (v, k),
        }
    }
}

/// The first crossing of the surface f = 0 along o + t·d for t in [t0, t1]: from outside
/// (f > 0 at t0) the first t where f ≤ 0, from inside (f < 0 at t0) the first where f ≥ 0 —
/// the exit, as the closed-form intersectors report for rays starting in a solid. A start on
/// the surface (its enclosure holds 0) counts as outside.
pub fn first_crossing(
    program: &Program,
    o: DVec3,
    d: DVec3,
    t0: f64,
    t1: f64,
    search: &Search,
    regs: &mut Registers,
) -> Root {
    if t0.is_nan() || t1.is_nan() || t0 > t1 {
        return Root::None { touched: 0 };
    }
    let start = at(program, o, d, t0, regs);
    let sign = if start.hi < 0.0 { -1.0 } else { 1.0 };
    let signed = |v: Interval| if sign > 0.0 { v } else { v.neg() };
    let mut arena = Arena {
        root: program,
        pruned: Vec::new(),
    };
    let mut stack = vec![(t0, t1, 0usize)];
    let mut boxes = 0u32;
    let mut touched = 0u32;
    while let Some((a, b, k)) = stack.pop() {
        boxes += 1;
        if boxes > search.max_boxes {
            return Root::Uncertified;
        }
        let (v, k) = arena.eval(k, sweep(o, d, a, b), regs);
        if signed(v).lo > 0.0 {
            continue;
        }
        let m = 0.5 * (a + b);
        if let Some(reach) = search.reach(d, a, b)
            && signed(at(arena.get(k), o, d, m, regs)).lo > reach
        {
            continue;
        }
        if b - a <= search.delta || m <= a || m >= b {
            let [x, y, z] = sweep(o, d, b, b);
            if signed(arena.get(k).eval(x, y, z, regs)).hi <= 0.0 {
                return Root::Crossing(Crossing {
                    lo: a,
                    hi: b,
                    touched,
                });
            }
            touched += 1;
            continue;
        }
        stack.push((m, b, k));
        stack.push((a, m, k));
    }
    Root::None { touched }
}

/// Whether f ≥ `level` all along o + t·d for t in [t0, t1]: `Some(true)` certified (every
/// stretch's enclosure is ≥ level, or for a stretch of width ≤ δ its midpoint's enclosure
/// less half the width, f being 1-Lipschitz), `Some(false)` certified not (a point's
/// enclosure lies below level), `None` when the search ran out of boxes or a stretch of
/// width ≤ δ is left undecided. This is the certified minimum of f along the ray, asked as a
/// decision.
pub fn stays_above(
    program: &Program,
    o: DVec3,
    d: DVec3,
    (t0, t1): (f64, f64),
    level: f64,
    search: &Search,
    regs: &mut Registers,
) -> Option<bool> {
    if t0.is_nan() || t1.is_nan() || t0 > t1 {
        return Some(true);
    }
    let mut arena = Arena {
        root: program,
        pruned: Vec::new(),
    };
    let mut stack = vec![(t0, t1, 0usize)];
    let mut boxes = 0u32;
    let mut undecided = false;
    while let Some((a, b, k)) = stack.pop() {
        boxes += 1;
        if boxes > search.max_boxes {
            return None;
        }
        let (v, k) = arena.eval(k, sweep(o, d, a, b), regs);
        if v.lo >= level {
            continue;
        }
        let m = 0.5 * (a + b);
        let [x, y, z] = sweep(o, d, m, m);
        let at_m = arena.get(k).eval(x, y, z, regs);
        if at_m.hi < level {
            return Some(false);
        }
        if let Some(reach) = search.reach(d, a, b)
            && at_m.lo - reach >= level
        {
            continue;
        }
        if b - a <= search.delta || m <= a || m >= b {
            // A stretch this narrow whose enclosure still reaches below the level: where a
            // branch boundary lies inside it (a `Select` whose condition changes sign, as
            // between the faces of Quilez's exact octahedron), the enclosure is the union of
            // both branches' however narrow the stretch, and bisection cannot settle it. The
            // field is 1-Lipschitz along the unit ray, so on the stretch it is at least the
            // midpoint's value less half the width; a point's enclosure decides its branch.
            if at_m.lo - 0.5 * (b - a) < level {
                undecided = true;
            }
            continue;
        }
        stack.push((m, b, k));
        stack.push((a, m, k));
    }
    (!undecided).then_some(true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sdf::SdfNode;
    use std::path::Path;

    fn program(shape: &str) -> Program {
        let src = format!(
            "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
                   objects: [(shape: {shape})])"
        );
        let scene = crate::scene::Scene::from_source(&src, Path::new("certified-test.ron"))
            .unwrap_or_else(|e| panic!("{e}"));
        let _: &SdfNode = &scene.objects[0].node;
        Program::new(&scene.objects[0].lowered.distance)
    }

    const SEARCH: Search = Search {
        delta: 1e-9,
        max_boxes: 100_000,
        lipschitz: None,
    };

    /// A unit sphere seen from z = 5: the crossing is enclosed in δ around t = 4, and from
    /// inside the exit is found.
    #[test]
    fn a_sphere_is_crossed_where_its_closed_form_says() {
        let p = program("Sphere(radius: 1)");
        let mut r = super::super::interval64::registers();
        let (o, d) = (DVec3::new(0.0, 0.0, 5.0), DVec3::NEG_Z);
        match first_crossing(&p, o, d, 0.0, 100.0, &SEARCH, &mut r) {
            Root::Crossing(c) => {
                assert!(c.lo <= 4.0 && 4.0 <= c.hi && c.hi - c.lo <= 1e-9, "{c:?}");
            }
            other => panic!("{other:?}"),
        }
        match first_crossing(&p, DVec3::ZERO, d, 0.0, 100.0, &SEARCH, &mut r) {
            Root::Crossing(c) => assert!(c.lo <= 1.0 && 1.0 <= c.hi, "{c:?}"),
            other => panic!("{other:?}"),
        }
        // A ray passing 0.001 beside it crosses nothing, and stays above 0.0009 but not 0.0011.
        let o = DVec3::new(1.001, 0.0, 5.0);
        assert!(matches!(
            first_crossing(&p, o, d, 0.0, 100.0, &SEARCH, &mut r),
            Root::None { touched: 0 }
        ));
        assert_eq!(
            stays_above(&p, o, d, (0.0, 100.0), 0.0009, &SEARCH, &mut r),
            Some(true)
        );
        assert_eq!(
            stays_above(&p, o, d, (0.0, 100.0), 0.0011, &SEARCH, &mut r),
            Some(false)
        );
        // Too few boxes: uncertified, not a guess.
        let tight = Search {
            max_boxes: 5,
            ..SEARCH
        };
        assert_eq!(
            first_crossing(&p, DVec3::new(0.0, 0.0, 5.0), d, 0.0, 100.0, &tight, &mut r),
            Root::Uncertified
        );
    }

    /// A shadow ray leaving a smoothly blended shell skims it at 1.5·10⁻³ to 4·10⁻³ for a
    /// tenth of a unit (a tree the property test drew): the sweep boxes' enclosures stay
    /// loose there, and bisection alone runs out of 20,000 boxes; the Lipschitz bound drops
    /// the stretches at once and certifies the miss in a few hundred.
    #[test]
    fn a_ray_skimming_a_blended_shell_is_certified_by_the_lipschitz_bound() {
        let p = program(
            "Onion(thickness: 0.046525143, shape: SmoothUnion(k: 0.13847673, shapes: [\
             Octahedron(size: 0.14286256), HexPrism(radius: 0.22602104, half_length: 0.11174729), \
             Capsule(a: (0.16238219, 0.29012597, 0), b: (0.29012597, 0, 0.16238219), \
             radius: 0.09046889)]))",
        );
        let mut r = super::super::interval64::registers();
        let o = DVec3::new(
            -0.1440068930387497,
            -0.13512368500232697,
            0.07795532047748566,
        ) - DVec3::new(-0.21303546, -0.027553627, -0.09540652);
        let d = DVec3::new(-0.26832816004753113, 0.8944271802902222, 0.3577708899974823);
        let search = |boxes, lipschitz| Search {
            delta: 1.6e-6,
            max_boxes: boxes,
            lipschitz,
        };
        let (t0, t1) = (0.0, 0.5);
        assert_eq!(
            first_crossing(&p, o, d, t0, t1, &search(20_000, None), &mut r),
            Root::Uncertified
        );
        assert!(matches!(
            first_crossing(&p, o, d, t0, t1, &search(500, Some(1.0)), &mut r),
            Root::None { .. }
        ));
        // the same settles the certificate that f stays above half its smallest value
        assert_eq!(
            stays_above(&p, o, d, (t0, t1), 5e-4, &search(500, Some(1.0)), &mut r),
            Some(true)
        );
        // and the bound drops no crossing: a ray into the shell still meets it
        let into = DVec3::new(0.0, 0.0, 1.0);
        assert!(matches!(
            first_crossing(
                &p,
                into,
                -DVec3::Z,
                0.0,
                2.0,
                &search(20_000, Some(1.0)),
                &mut r
            ),
            Root::Crossing(_)
        ));
    }

    /// A union of two spheres, the near one small: the first crossing is the near one's, and a
    /// plate thinner than any sphere tracer's ε (10⁻⁶) is still found.
    #[test]
    fn the_first_root_is_found_before_a_later_one_and_thin_plates_are_not_skipped() {
        let p = program(
            "Union([Transform(translate: (0, 0, 2), shape: Sphere(radius: 0.01)), Sphere(radius: 1)])",
        );
        let mut r = super::super::interval64::registers();
        let (o, d) = (DVec3::new(0.0, 0.0, 5.0), DVec3::NEG_Z);
        match first_crossing(&p, o, d, 0.0, 100.0, &SEARCH, &mut r) {
            Root::Crossing(c) => {
                // the radius is the f32 nearest 0.01
                let root = 3.0 - 0.01f32 as f64;
                assert!(c.lo <= root && root <= c.hi, "{c:?}");
            }
            other => panic!("{other:?}"),
        }
        let plate = program("Box(half_extents: (1, 1, 0.000001))");
        match first_crossing(&plate, o, d, 0.0, 100.0, &SEARCH, &mut r) {
            Root::Crossing(c) => assert!((c.hi - 4.999999).abs() < 1e-8, "{c:?}"),
            other => panic!("{other:?}"),
        }
    }
}
