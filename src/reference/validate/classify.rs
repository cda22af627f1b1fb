//! One ray's outcome: whether the two sides agree, disagree at a silhouette (in the band) or
//! disagree elsewhere, with the tolerance formulas that decide it.

use super::SdfCheck;
use super::probes::{Probe, ShadowProbe};
use crate::accel::field::FieldCursor;
use crate::geom::{Aabb, Ray};
use crate::reference::certified::{self, Search};
use crate::reference::interval64::{self, Program};
use crate::scene::Scene;
use crate::sdf::tape::Registers;
use crate::trace::epsilon_at;
use crate::trace::query::{ObjectId, QueryHit, RayQuery};
use glam::Vec3;
use serde::Serialize;

/// Below this |n·d| a ray grazes a surface: a hit/miss disagreement there is at a silhouette.
pub const GRAZING: f32 = 0.05;
/// Largest mesh |Δt| as a fraction of the scene's diameter.
pub const MESH_DT_OF_DIAMETER: f32 = 1e-4;

/// How far apart two tracers' hit distances on one SDF surface may be: a sphere tracer stops
/// within ε(t) of the surface, up to ε(t)/|n·d| before it along the ray (Hart 1996), so two
/// of them may differ by twice that; a surface the referee holds only to within `tau` (a
/// mesh of the field, whose facets stand up to `tau` off it) adds `tau/|n·d|`; and 10·ε(t)
/// is allowed in any case. `cos` is |n·d| at the hit (clamped away from 0). The one formula
/// of `validate`, the Embree reference tests and the GPU tests.
pub fn sdf_dt_tolerance(
    settings: &crate::scene::TracerSettings,
    t: f32,
    cos: f32,
    tau: f32,
) -> f32 {
    let e = epsilon_at(settings, t);
    (10.0 * e).max((2.0 * e + tau) / cos.max(1e-6))
}

/// How far apart two tracers' hit distances on one triangle may be: [`MESH_DT_OF_DIAMETER`]
/// of the scene's diameter (both are watertight ray–triangle tests in f32).
pub fn mesh_dt_tolerance(diameter: f32) -> f32 {
    MESH_DT_OF_DIAMETER * diameter
}

/// The kind of object a ray is classified by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    /// A triangle-mesh instance.
    Mesh,
    /// An SDF object the referee intersects in closed form.
    AnalyticSdf,
    /// An SDF object the referee intersects by the certified root search of its tape.
    CertifiedSdf,
    /// An SDF object the referee intersects as an extracted mesh.
    MeshedSdf,
    /// An SDF object the referee skipped (only our side can hit it).
    UncheckedSdf,
}

impl Kind {
    /// Every kind, in table order.
    pub const ALL: [Kind; 5] = [
        Kind::Mesh,
        Kind::AnalyticSdf,
        Kind::CertifiedSdf,
        Kind::MeshedSdf,
        Kind::UncheckedSdf,
    ];

    /// The name in tables.
    pub fn label(self) -> &'static str {
        match self {
            Kind::Mesh => "mesh",
            Kind::AnalyticSdf => "analytic SDF",
            Kind::CertifiedSdf => "certified SDF",
            Kind::MeshedSdf => "meshed SDF",
            Kind::UncheckedSdf => "unchecked SDF",
        }
    }

    pub(super) fn index(self) -> usize {
        self as usize
    }
}

/// The outcome of one ray.
#[derive(Debug, Clone, Copy)]
pub(super) enum Outcome {
    BothMiss,
    Agree { kind: Kind, dt: f32, tol: f32 },
    Disagree { kind: Kind, in_band: bool },
    Unchecked,
    OutsideMesh,
}

/// A camera or random ray with both sides' answers and its outcome.
#[derive(Debug, Clone, Copy)]
pub(super) struct Classified {
    pub(super) probe: Probe,
    pub(super) ours: Option<QueryHit>,
    pub(super) referee: Option<QueryHit>,
    pub(super) outcome: Outcome,
}

/// A shadow ray's outcome: the kind of the hit it leaves, whether both agree, whether it
/// leaves at a grazing angle.
#[derive(Debug, Clone, Copy)]
pub(super) struct ShadowOutcome {
    pub(super) kind: Kind,
    pub(super) agree: bool,
    pub(super) grazing: bool,
    pub(super) outside_mesh: bool,
    pub(super) within_mesh_tolerance: bool,
}

/// Classifies rays of `scene` asked of `ours` and of `referee`, which represents SDF object i
/// as `checks[i]`.
pub(super) struct Classifier<'a, A: ?Sized, B: ?Sized> {
    scene: &'a Scene,
    ours: &'a A,
    referee: &'a B,
    checks: &'a [SdfCheck],
    /// The mesh |Δt| tolerance.
    mesh_tol: f32,
    /// Per SDF object checked by the certified search: its program and search bounds.
    certified: Vec<Option<(Program, Search)>>,
    /// Per SDF object checked in closed form: its program and the certified search's bounds
    /// (for the depth of a sliver the closed form crosses, which it does not tell).
    closed_form: Vec<Option<(Program, Search)>>,
}

impl<'a, A, B> Classifier<'a, A, B>
where
    A: RayQuery + ?Sized,
    B: RayQuery + ?Sized,
{
    /// The classifier of `ours` against `referee`, meshes held to `mesh_tol`.
    pub(super) fn new(
        scene: &'a Scene,
        ours: &'a A,
        referee: &'a B,
        checks: &'a [SdfCheck],
        mesh_tol: f32,
    ) -> Self {
        let certified = checks
            .iter()
            .zip(&scene.objects)
            .map(|(c, o)| match *c {
                SdfCheck::Certified {
                    delta,
                    max_boxes,
                    lipschitz,
                } => Some((
                    Program::new(&o.lowered.distance),
                    Search {
                        delta,
                        max_boxes,
                        lipschitz,
                    },
                )),
                _ => None,
            })
            .collect();
        let closed_form = checks
            .iter()
            .zip(&scene.objects)
            .map(|(c, o)| {
                matches!(c, SdfCheck::Analytic).then(|| {
                    let mut search = certified::certified_search(&scene.tracer);
                    search.lipschitz = o.node.guaranteed_lipschitz().map(f64::from);
                    (Program::new(&o.lowered.distance), search)
                })
            })
            .collect();
        Classifier {
            scene,
            ours,
            referee,
            checks,
            mesh_tol,
            certified,
            closed_form,
        }
    }

    /// The kind an object is classified under.
    pub(super) fn kind_of(&self, object: ObjectId) -> Kind {
        match object {
            ObjectId::MeshInstance(_) => Kind::Mesh,
            ObjectId::Sdf(i) => match self.checks.get(i) {
                Some(SdfCheck::Analytic) => Kind::AnalyticSdf,
                Some(SdfCheck::Certified { .. }) => Kind::CertifiedSdf,
                Some(SdfCheck::Meshed { .. }) => Kind::MeshedSdf,
                _ => Kind::UncheckedSdf,
            },
        }
    }

    /// δ of a certified object (the width its roots are enclosed in), 0 for any other.
    fn delta(&self, object: ObjectId) -> f32 {
        match object {
            ObjectId::Sdf(i) => match self.checks.get(i) {
                Some(SdfCheck::Certified { delta, .. }) => *delta as f32,
                _ => 0.0,
            },
            ObjectId::MeshInstance(_) => 0.0,
        }
    }

    /// The certified program of `hit`'s object, if it is checked by the certified search.
    fn certified_of(&self, object: ObjectId) -> Option<&(Program, Search)> {
        match object {
            ObjectId::Sdf(i) => self.certified.get(i)?.as_ref(),
            ObjectId::MeshInstance(_) => None,
        }
    }

    /// Our hit `x` on a certified object that the referee did not cross there: a near miss,
    /// excused when the ray passes within ε(t) of the surface at our hit — the certified
    /// enclosure of the field at our hit point lies at or below ε(t) (Hart's stopping rule:
    /// a sphere tracer may stop wherever f < ε(t)). Never excused by a grazing angle alone.
    fn certified_near_miss(&self, x: &QueryHit, ray: &Ray) -> bool {
        let Some((program, _)) = self.certified_of(x.object) else {
            return false;
        };
        let e = epsilon_at(&self.scene.tracer, x.t) as f64;
        let (o, d) = (ray.origin.as_dvec3(), ray.direction.as_dvec3());
        let f = certified::at(program, o, d, x.t as f64, &mut interval64::registers());
        f.hi <= e
    }

    /// The referee's crossing `y` of a certified object, which our tracer did not report
    /// before `end`: a sliver, excused when the ray never goes deeper than ε(t)/2 into the
    /// solid on [y.t − δ, end] (the certified minimum of f there is ≥ −ε(t)/2). The field is
    /// 1-Lipschitz, so a chord with a point deeper than ε/2 is longer than ε — more of the
    /// ray than a sphere tracer's confirmation may step over (`crate::trace::crossing`).
    fn certified_sliver(&self, y: &QueryHit, ray: &Ray, end: f32) -> bool {
        let Some((program, search)) = self.certified_of(y.object) else {
            return false;
        };
        self.sliver_of(program, search, y, ray, end)
    }

    /// The closed form's crossing `y`, which our tracer did not report before `end`: a
    /// sliver by the rule of [`Self::certified_sliver`], the depth certified on the object's
    /// field (the closed form gives where the ray crosses the surface, not how deep it goes:
    /// a ray clipping a cone's rim 4·10⁻⁶ deep, head on to the base, was counted as a miss
    /// of ours away from any silhouette).
    fn closed_form_sliver(&self, y: &QueryHit, ray: &Ray, end: f32) -> bool {
        let Some(Some((program, search))) = (match y.object {
            ObjectId::Sdf(i) => self.closed_form.get(i),
            ObjectId::MeshInstance(_) => None,
        }) else {
            return false;
        };
        self.sliver_of(program, search, y, ray, end)
    }

    /// Whether the ray goes no deeper than ε(t)/2 into the solid of `program` on
    /// [y.t − δ, end].
    fn sliver_of(
        &self,
        program: &Program,
        search: &Search,
        y: &QueryHit,
        ray: &Ray,
        end: f32,
    ) -> bool {
        let e = epsilon_at(&self.scene.tracer, y.t) as f64;
        let (o, d) = (ray.origin.as_dvec3(), ray.direction.as_dvec3());
        let span = ((y.t as f64 - search.delta).max(0.0), end as f64);
        certified::stays_above(
            program,
            o,
            d,
            span,
            -0.5 * e,
            search,
            &mut interval64::registers(),
        ) == Some(true)
    }

    /// τ of a meshed object, 0 for any other.
    pub(super) fn meshed_tolerance(&self, object: ObjectId) -> f32 {
        match object {
            ObjectId::Sdf(i) => match self.checks.get(i) {
                Some(SdfCheck::Meshed { tolerance, .. }) => *tolerance,
                _ => 0.0,
            },
            ObjectId::MeshInstance(_) => 0.0,
        }
    }

    /// The grid cell of a meshed object, 0 for any other.
    fn meshed_cell(&self, object: ObjectId) -> f32 {
        match object {
            ObjectId::Sdf(i) => match self.checks.get(i) {
                Some(SdfCheck::Meshed { cell, .. }) => *cell,
                _ => 0.0,
            },
            ObjectId::MeshInstance(_) => 0.0,
        }
    }

    /// Whether `hit` lies where a clipped unbounded meshed object has no mesh: outside its box,
    /// shrunk by the tolerance (a hit that close to the box's faces may belong to a cut-off
    /// triangle).
    fn outside_mesh(&self, hit: &QueryHit, ray: &Ray) -> bool {
        let mesh_box = match hit.object {
            ObjectId::Sdf(i) => match self.checks.get(i) {
                Some(SdfCheck::Meshed {
                    clipped_to: Some([lo, hi]),
                    tolerance,
                    ..
                }) => Some((Aabb::new(Vec3::from(*lo), Vec3::from(*hi)), *tolerance)),
                _ => None,
            },
            ObjectId::MeshInstance(_) => None,
        };
        mesh_box.is_some_and(|(b, tol)| b.signed_distance(ray.at(hit.t)) > -tol)
    }

    /// The |Δt| tolerance at the referee's hit (see the module documentation).
    fn tolerance(&self, hit: &QueryHit, ray: &Ray) -> f32 {
        let settings = &self.scene.tracer;
        let cos = hit.normal.dot(ray.direction).abs();
        match self.kind_of(hit.object) {
            Kind::Mesh => self.mesh_tol,
            Kind::AnalyticSdf => sdf_dt_tolerance(settings, hit.t, cos, 0.0),
            Kind::CertifiedSdf => sdf_dt_tolerance(settings, hit.t, cos, self.delta(hit.object)),
            Kind::MeshedSdf => {
                sdf_dt_tolerance(settings, hit.t, cos, self.meshed_tolerance(hit.object))
            }
            Kind::UncheckedSdf => f32::INFINITY,
        }
    }

    /// Half-width of the band around a surface in which a hit/miss disagreement is excused.
    fn band(&self, hit: &QueryHit) -> f32 {
        let e = epsilon_at(&self.scene.tracer, hit.t);
        match self.kind_of(hit.object) {
            Kind::Mesh => 0.0,
            Kind::AnalyticSdf | Kind::CertifiedSdf | Kind::UncheckedSdf => 3.0 * e,
            Kind::MeshedSdf => self.meshed_tolerance(hit.object) + 3.0 * e,
        }
    }

    /// Whether `other` has a surface within the band of `hit`: a probe along the normal
    /// through the hit point, from one band-width outside to one band-width inside.
    fn near<Q: RayQuery + ?Sized>(&self, other: &Q, hit: &QueryHit, ray: &Ray) -> bool {
        let occluded = |r: &Ray, len: f32| other.occluded(r, 0.0, len);
        if self.kind_of(hit.object) == Kind::Mesh {
            // Both sides intersect the same triangles exactly: only grazing rays are excused.
            return false;
        }
        let w = self.band(hit);
        let n = hit.normal.normalize_or_zero();
        if n == Vec3::ZERO {
            return false;
        }
        let p = ray.at(hit.t);
        if occluded(&Ray::new(p + w * n, -n), 2.0 * w) {
            return true;
        }
        let settings = &self.scene.tracer;
        // A meshed hit's facet normal is not the surface's: probe along the field's gradient
        // at the hit point too (the direction to the nearest true surface).
        if let ObjectId::Sdf(i) = hit.object
            && self.kind_of(hit.object) == Kind::MeshedSdf
        {
            let s = settings;
            let g = crate::trace::normal::estimate(
                &mut FieldCursor::whole(
                    &self.scene.objects[i].lowered.distance,
                    &mut Registers::new(),
                ),
                p,
                crate::trace::normal::step_for(s, hit.t, p),
                s.normals,
            )
            .0
            .normalize_or_zero();
            if g != Vec3::ZERO && occluded(&Ray::new(p + w * g, -g), 2.0 * w) {
                return true;
            }
        }
        // A meshed object's tolerance bounds how far the mesh strays from the surface, not the
        // converse: at a sharp edge or a thin rim marching cubes cuts the corner, and the
        // surface there can lie up to a cell diagonal from the mesh in a direction other than
        // its normal (the mesher's docs: features thinner than a cell can be lost). So a
        // meshed object's band is also probed along the three axes and the ray, a cell
        // diagonal (+ 3·ε(t)) each way, and along the four cube diagonals.
        let cell = self.meshed_cell(hit.object);
        if cell == 0.0 {
            return false;
        }
        let w = 3f32.sqrt() * cell + 3.0 * epsilon_at(settings, hit.t);
        // The axes and the cube diagonals: marching cubes cuts an edge of the solid by a
        // facet facing between two axes, a corner by one facing along a diagonal.
        let d = 1.0 / 3f32.sqrt();
        [
            Vec3::X,
            Vec3::Y,
            Vec3::Z,
            Vec3::new(d, d, d),
            Vec3::new(d, d, -d),
            Vec3::new(d, -d, d),
            Vec3::new(-d, d, d),
            ray.direction,
        ]
        .iter()
        .any(|&a| occluded(&Ray::new(p - w * a, a), 2.0 * w))
    }

    /// Our hit on a meshed object where the ray only clips a sliver of the true solid (an
    /// edge, a rim, a plate thinner than a cell): the object's field, sampled every quarter
    /// cell along the ray past the hit, is outside again within a cell diagonal. Marching
    /// cubes may lose such a sliver (the mesher's docs), so the referee's miss is at a
    /// silhouette.
    fn sliver(&self, hit: &QueryHit, ray: &Ray) -> bool {
        let cell = self.meshed_cell(hit.object);
        match hit.object {
            ObjectId::Sdf(i) if cell > 0.0 => {
                let field = &self.scene.objects[i].lowered.distance;
                (1..=7).any(|k| field.eval(ray.at(hit.t + 0.25 * k as f32 * cell)) > 0.0)
            }
            _ => false,
        }
    }

    /// A sphere tracer stops up to ε(t)/|n·d| before the surface, so near the end of the ray
    /// range it can report a surface that lies just beyond tmax, which the referee (stopping
    /// at tmax exactly) does not see. Such a hit agrees when the referee finds the same object
    /// within tolerance on the ray extended by that tolerance.
    fn beyond_the_end(&self, x: &QueryHit, ray: &Ray) -> Option<QueryHit> {
        let settings = &self.scene.tracer;
        let tmax = settings.max_distance;
        let cos = x.normal.dot(ray.direction).abs().max(1e-6);
        let reach =
            sdf_dt_tolerance(settings, x.t, cos, 0.0) + self.meshed_tolerance(x.object) / cos;
        if x.t + reach <= tmax {
            return None;
        }
        let y = self.referee.closest_hit(ray, 0.0, x.t + reach)?;
        (y.object == x.object && y.t > tmax && (x.t - y.t).abs() <= self.tolerance(&y, ray))
            .then_some(y)
    }

    /// A hit only our side has: counted under the object's kind, unless the referee skipped
    /// that object (then there is nothing to compare with); in the band when the ray grazes
    /// the surface, or the referee has a surface within its band, or the ray only clips a
    /// sliver of a meshed object.
    fn only_ours(&self, x: &QueryHit, ray: &Ray) -> Outcome {
        let kind = self.kind_of(x.object);
        if kind == Kind::UncheckedSdf {
            Outcome::Unchecked
        } else if kind == Kind::CertifiedSdf {
            Outcome::Disagree {
                kind,
                in_band: self.certified_near_miss(x, ray),
            }
        } else {
            Outcome::Disagree {
                kind,
                in_band: grazing(x, ray)
                    || (self.near(self.referee, x, ray) || self.sliver(x, ray)),
            }
        }
    }

    /// A hit only the referee has (before ours, if any): in the band when the ray grazes the
    /// surface, our tracer has a surface within its band, or the ray only clips a sliver.
    fn only_referee(&self, y: &QueryHit, ray: &Ray) -> Outcome {
        if self.kind_of(y.object) == Kind::CertifiedSdf {
            let end = self.scene.tracer.max_distance;
            return Outcome::Disagree {
                kind: Kind::CertifiedSdf,
                in_band: self.certified_sliver(y, ray, end),
            };
        }
        let end = self.scene.tracer.max_distance;
        Outcome::Disagree {
            kind: self.kind_of(y.object),
            in_band: grazing(y, ray)
                || self.near(self.ours, y, ray)
                || self.closed_form_sliver(y, ray, end),
        }
    }

    /// Asks both sides for the closest hit along `probe` and classifies the answers.
    pub(super) fn classify(&self, probe: &Probe) -> Classified {
        let ray = &probe.ray;
        let tmax = self.scene.tracer.max_distance;
        let a = self.ours.closest_hit(ray, 0.0, tmax);
        let b = self.referee.closest_hit(ray, 0.0, tmax);
        let outcome = match (&a, &b) {
            (None, None) => Outcome::BothMiss,
            // Our hit lies where the referee has no mesh for the surface, and the referee
            // sees nothing before it: nothing to compare.
            (Some(x), _)
                if self.outside_mesh(x, ray)
                    && b.is_none_or(|y| y.t > x.t - self.tolerance(x, ray)) =>
            {
                Outcome::OutsideMesh
            }
            (Some(x), Some(y)) => self.both_hit(x, y, ray),
            (Some(x), None) => match self.beyond_the_end(x, ray) {
                Some(y) => Outcome::Agree {
                    kind: self.kind_of(y.object),
                    dt: (x.t - y.t).abs(),
                    tol: self.tolerance(&y, ray),
                },
                None => self.only_ours(x, ray),
            },
            (None, Some(y)) => self.only_referee(y, ray),
        };
        Classified {
            probe: *probe,
            ours: a,
            referee: b,
            outcome,
        }
    }

    /// Both sides hit: our hit `x`, the referee's `y`.
    fn both_hit(&self, x: &QueryHit, y: &QueryHit, ray: &Ray) -> Outcome {
        // τ bounds the mesh's distance from the surface along the surface's normal, so along
        // the ray it is τ/|n·d|. Near a crease the mesh cuts (an edge of a twisted box, a rim)
        // the surface has every normal between the two faces', ours (from the field, one face)
        // and the facet's (the chamfer, between them): the tolerance takes the more grazing of
        // the two.
        let tol = if x.object == y.object && self.kind_of(y.object) == Kind::MeshedSdf {
            let facet = y.normal.dot(ray.direction).abs();
            let normal = if x.normal.dot(ray.direction).abs() < facet {
                x.normal
            } else {
                y.normal
            };
            self.tolerance(&QueryHit { normal, ..*y }, ray)
        } else {
            self.tolerance(y, ray)
        };
        let dt = (x.t - y.t).abs();
        let certified = |h: &QueryHit| self.kind_of(h.object) == Kind::CertifiedSdf;
        if dt > tol && (certified(x) || certified(y)) {
            // The nearer hit is one side's alone: excused only by the certified field (a near
            // miss of ours, a sliver the referee crossed); on one object, an unexcused
            // difference is a |Δt| over tolerance, on two a hit/miss disagreement.
            let (kind, in_band) = if x.t < y.t {
                (self.kind_of(x.object), self.certified_near_miss(x, ray))
            } else {
                (self.kind_of(y.object), self.certified_sliver(y, ray, x.t))
            };
            return if in_band {
                Outcome::Disagree {
                    kind,
                    in_band: true,
                }
            } else if x.object == y.object {
                Outcome::Agree { kind, dt, tol }
            } else if x.t < y.t {
                self.only_ours(x, ray)
            } else {
                self.only_referee(y, ray)
            };
        }
        if dt > tol && x.t < y.t && (self.near(self.referee, x, ray) || self.sliver(x, ray)) {
            // Our hit lies within the band of the referee's surface, which the ray passes by:
            // a sphere tracer's near miss at a silhouette (it stops wherever the ray comes
            // within ε(t) of a surface), then the referee meets the same or another surface
            // farther on.
            Outcome::Disagree {
                kind: self.kind_of(x.object),
                in_band: true,
            }
        } else if dt > tol
            && x.t > y.t
            && self.kind_of(y.object) == Kind::MeshedSdf
            && self.near(self.ours, y, ray)
        {
            // The referee's mesh, standing up to τ proud of the surface, meets a ray that
            // passes the true surface within the band: our tracer rightly goes on to a farther
            // surface (of the same object or not).
            Outcome::Disagree {
                kind: self.kind_of(y.object),
                in_band: true,
            }
        } else if x.object != y.object && dt > tol {
            // Different surfaces: a hit/miss disagreement on the nearer one.
            if x.t < y.t {
                self.only_ours(x, ray)
            } else {
                self.only_referee(y, ray)
            }
        } else {
            Outcome::Agree {
                kind: self.kind_of(y.object),
                dt,
                tol,
            }
        }
    }

    /// Asks both sides whether `shadow` is blocked and classifies the answers; `kind` is the
    /// kind of the camera-ray hit it leaves.
    pub(super) fn classify_shadow(&self, shadow: &ShadowProbe, kind: Kind) -> ShadowOutcome {
        let (ray, len) = (&shadow.ray, shadow.len);
        let ours_occluded = self.ours.occluded(ray, 0.0, len);
        let agree = ours_occluded == self.referee.occluded(ray, 0.0, len);
        // Our occluder is where the referee has no mesh for it: nothing to compare.
        let outside_mesh = !agree
            && ours_occluded
            && self
                .ours
                .closest_hit(ray, 0.0, len)
                .is_some_and(|h| self.outside_mesh(&h, ray));
        // The blocker is a meshed object and the ray passes within the mesh's tolerance of
        // it: at that distance the mesh cannot say whether the true surface blocks.
        let within_mesh_tolerance = !agree
            && !outside_mesh
            && if ours_occluded {
                self.ours.closest_hit(ray, 0.0, len).is_some_and(|x| {
                    self.kind_of(x.object) == Kind::MeshedSdf
                        && (self.near(self.referee, &x, ray) || self.sliver(&x, ray))
                })
            } else {
                self.referee
                    .closest_hit(ray, 0.0, len)
                    .is_some_and(|y| match y.object {
                        ObjectId::Sdf(i) if self.kind_of(y.object) == Kind::MeshedSdf => {
                            self.scene.objects[i].lowered.distance.eval(ray.at(y.t))
                                >= -3.0 * epsilon_at(&self.scene.tracer, y.t)
                        }
                        _ => false,
                    })
            };
        // A disagreement on a certified blocker the ray passes within ε(t) of is a grazing
        // one: still counted against the agreement, and told apart in the report.
        let certified_band = !agree
            && if ours_occluded {
                self.ours
                    .closest_hit(ray, 0.0, len)
                    .is_some_and(|x| self.certified_near_miss(&x, ray))
            } else {
                self.referee
                    .closest_hit(ray, 0.0, len)
                    .is_some_and(|y| self.certified_sliver(&y, ray, len))
            };
        ShadowOutcome {
            kind,
            agree,
            grazing: shadow.cos < GRAZING || certified_band,
            outside_mesh,
            within_mesh_tolerance,
        }
    }
}

/// Whether the ray meets `hit`'s surface at a grazing angle (|n·d| < [`GRAZING`]).
fn grazing(hit: &QueryHit, ray: &Ray) -> bool {
    hit.normal.dot(ray.direction).abs() < GRAZING
}
