//! Ray-by-ray validation of one backend against a referee: the same rays (every pixel's camera
//! ray, random rays through the scene, shadow rays toward every light) asked of both through
//! [`RayQuery`], compared on hit/miss, hit distance and occlusion per object kind, against the
//! thresholds below.
//!
//! The comparison ([`validate`]) is generic over the two backends, so the GPU can be checked
//! the same way; [`validate_with_embree`] (feature `embree`) checks our CPU tracer against
//! Embree 4.
//!
//! **Thresholds and tolerances** (t is the referee's hit distance, n its unit normal, d the unit
//! ray direction, ε(t) = ε₀ + ε₁·t the tracer's hit threshold, D the diameter of the scene's
//! finite bounds):
//!
//! | kind | hit/miss agreement | \|Δt\| tolerance | hit/miss disagreements |
//! |---|---|---|---|
//! | mesh | ≥ 99.99 % | 1e-4·D | counted (band: grazing) |
//! | analytic SDF | ≥ 99.9 % | max(10·ε(t), 2·ε(t)/\|n·d\|) | only inside the ε band |
//! | certified SDF | ≥ 99.9 % | max(10·ε(t), (2·ε(t) + δ)/\|n·d\|) | only a certified near miss or sliver |
//! | meshed SDF | — | max(10·ε(t), (τ + 2·ε(t))/\|n·d\|) | only inside the τ band |
//! | shadow rays | ≥ 99.9 % | — | counted (band: grazing) |
//!
//! Why the SDF tolerance grows as 1/|n·d|: a sphere tracer stops where the field drops below
//! ε(t), i.e. up to ε(t) before the surface *along its normal*, which is ε(t)/|n·d| along the
//! ray (Hart 1996, §4.2); the factor 2 covers the normal estimate and f32 rounding, and 10·ε(t)
//! is the floor for rays that meet the surface head-on. A meshed SDF's triangles lie
//! within the mesher's stated tolerance τ of the true surface, which adds τ/|n·d| along the
//! ray. "Inside the band" means the disagreement is at a silhouette: the ray grazes the
//! surface that one side hit (|n·d| < 0.05, [`GRAZING`]), or the surface one side hit lies
//! within the band width (3·ε(t) for analytic SDFs, τ + 3·ε(t) for meshed ones; not for meshes,
//! which both sides intersect exactly) of the other side's surface — found by a short probe ray
//! of the other backend along the normal (for a meshed hit also along the field's gradient,
//! the facet's normal being off); for meshed SDFs also where our ray only clips a sliver of
//! the true solid (the object's field, sampled every h/4 past our hit, is positive again
//! within √3·h, h the cell) or the other side's surface lies within a cell diagonal
//! √3·h + 3·ε(t) along the three axes, the four cube diagonals or the ray (τ bounds the
//! mesh's distance from the surface, not the surface's from the mesh: marching cubes cuts
//! sharp edges and corners and thin rims by up to a cell, and features thinner than a cell
//! can be lost). A referee hit on a meshed object before ours, with our tracer's surface
//! within that band, is such a silhouette disagreement too (the mesh stands proud of a
//! surface the ray passes). Every SDF object must be checked by the referee: an object it
//! skipped is a failure, as are all thresholds above.
//!
//! **Certified SDFs** (every SDF object without a closed form, unless `--meshed`): the referee's
//! root is certified within δ ([`super::certified`]), so no mesh cell enters any tolerance. A
//! disagreement is excused only by the certified field itself: our hit where the referee saw no
//! crossing is a near miss when the enclosure of f at our hit point is ≤ ε(t) (the ray passes
//! within ε(t) of the surface there, where Hart's rule may stop); a crossing the referee found
//! and we did not is a sliver when f stays ≥ −ε(t)/2 from it to our hit (or the ray's end), i.e.
//! the chord is at most ε(t) long — what a sphere tracer's confirmation may step over. Grazing
//! angles alone excuse nothing. Searches that ran out of interval evaluations are counted and
//! fail the validation beyond 0.1 % of the certified and shadow rays.
//!
//! **Clipped unbounded objects.** The referee meshes an unbounded object (infinite repetition)
//! only inside a box; a ray whose hit by our tracer lies outside that box (shrunk by the
//! mesher's tolerance) with no referee surface before it, and a disagreeing shadow ray whose
//! first occluder for our tracer lies there, have nothing to be compared with: they are left
//! out of every figure and counted in the report.
//!
//! **Shadow rays** start at the referee's camera-ray hit, offset along its normal as the
//! renderer offsets them, plus 2τ from a meshed SDF's hit (τ its tolerance): the mesh lies up to
//! τ from the true surface on either side, and a ray starting inside the true solid would see
//! the surface it leaves as its occluder. A shadow ray on which the two sides disagree about
//! a meshed blocker the ray passes within the mesh's tolerance of (our blocker within the band
//! of the referee's mesh; the referee's mesh blocking at a point outside the true solid) is
//! undecidable at that tolerance: it is left out of the agreement and counted.

mod aggregate;
mod classify;
mod output;
mod probes;

pub use super::check::SdfCheck;
pub use aggregate::{
    EXAMPLES, Example, KindRow, KindStats, MESH_AGREEMENT, ObjectEntry, PixelClass, Report,
    SDF_AGREEMENT, SHADOW_AGREEMENT, ShadowStats,
};
pub use classify::{GRAZING, Kind, MESH_DT_OF_DIAMETER, mesh_dt_tolerance, sdf_dt_tolerance};
pub use probes::{Options, scene_bounds};

use crate::scene::Scene;
use crate::trace::query::RayQuery;
use classify::{Classified, Classifier, ShadowOutcome};
use rayon::prelude::*;

/// Validates `ours` against `referee` on `scene`: `checks[i]` says how the referee represents
/// SDF object i. Rays are cast in parallel (rayon); the result does not depend on the thread
/// count. Fails only when the rays cannot be generated.
///
/// The pipeline: the probes (camera and random rays) are classified, then the shadow rays
/// from the referee's camera-ray hits, and the outcomes are summed into the report.
pub fn validate<A, B>(
    scene: &Scene,
    ours: &A,
    referee: &B,
    checks: &[SdfCheck],
    options: &Options,
) -> Result<Report, String>
where
    A: RayQuery + Sync + ?Sized,
    B: RayQuery + Sync + ?Sized,
{
    if options.width == 0 || options.height == 0 {
        return Err(format!(
            "the camera grid must be at least 1×1 (got {}×{})",
            options.width, options.height
        ));
    }
    if checks.len() != scene.objects.len() {
        return Err(format!(
            "{} object checks for {} SDF objects",
            checks.len(),
            scene.objects.len()
        ));
    }
    let diameter = scene_bounds(scene).diagonal();
    let mesh_tol = mesh_dt_tolerance(diameter);
    let classifier = Classifier::new(scene, ours, referee, checks, mesh_tol);

    let rays: Vec<Classified> = probes::probes(scene, options)?
        .par_iter()
        .map(|probe| classifier.classify(probe))
        .collect();
    let shadows: Vec<(usize, ShadowOutcome)> = rays
        .par_iter()
        .filter_map(|c| Some((c.probe.pixel?, c.probe.ray, c.referee?)))
        .flat_map_iter(|(pixel, ray, hit)| {
            let kind = classifier.kind_of(hit.object);
            let tau = classifier.meshed_tolerance(hit.object);
            let classifier = &classifier;
            probes::shadow_probes(scene, pixel, ray, hit, tau)
                .map(move |shadow| (shadow.pixel, classifier.classify_shadow(&shadow, kind)))
        })
        .collect();
    Ok(aggregate::report(
        scene, checks, options, diameter, mesh_tol, &rays, &shadows,
    ))
}

/// Validates our CPU tracer against Embree 4 on `scene`.
#[cfg(feature = "embree")]
pub fn validate_with_embree(scene: &Scene, options: &Options) -> Result<Report, String> {
    validate_with_embree_options(scene, options, &super::embree::ReferenceOptions::default())
}

/// Validates our CPU tracer against Embree 4 on `scene`, the referee built with `reference`.
#[cfg(feature = "embree")]
pub fn validate_with_embree_options(
    scene: &Scene,
    options: &Options,
    reference: &super::embree::ReferenceOptions,
) -> Result<Report, String> {
    let tracer = crate::trace::SceneTracer::new(scene);
    validate_against_embree(scene, &tracer, options, reference)
}

/// Validates `ours` against Embree 4 on `scene`, the referee built with `reference`: what
/// [`validate_with_embree_options`] does for our tracer, for any backend (a GPU readback, or
/// a deliberately broken tracer in the tests), with the certified searches that ran out of
/// interval evaluations added to the report.
#[cfg(feature = "embree")]
pub fn validate_against_embree<A: RayQuery + Sync + ?Sized>(
    scene: &Scene,
    ours: &A,
    options: &Options,
    reference: &super::embree::ReferenceOptions,
) -> Result<Report, String> {
    let embree = super::embree::EmbreeScene::build_with(scene, reference)?;
    let checks = embree.checks.clone();
    let mut report = validate(scene, ours, &embree, &checks, options)?;
    report.note_uncertified(embree.uncertified());
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Ray;
    use crate::sdf::tape::Registers;
    use crate::trace::query::QueryHit;
    use std::path::Path;

    fn scene() -> Scene {
        let src = "Scene(
            camera: Perspective(position: (0, 1, 6), look_at: (0, 0, 0), fov: 40),
            lights: [Point(position: (3, 5, 4), intensity: 10), Directional(direction: (0, -1, 0), intensity: 1)],
            objects: [
                (shape: Sphere(radius: 1)),
                (shape: Box(half_extents: (0.5, 0.5, 0.5)), translate: (2.2, 0, 0)),
                (shape: Plane(normal: (0, 1, 0), offset: -1)),
            ],
            tracer: (epsilon: 1e-4, epsilon_per_unit: 1e-4),
        )";
        Scene::from_source(src, Path::new("validate-test.ron")).unwrap_or_else(|e| panic!("{e}"))
    }

    const ANALYTIC: [SdfCheck; 3] = [SdfCheck::Analytic, SdfCheck::Analytic, SdfCheck::Analytic];

    fn options() -> Options {
        Options {
            width: 48,
            height: 36,
            random: 300,
            seed: 7,
        }
    }

    /// A backend compared with itself agrees on every ray.
    #[test]
    fn a_backend_agrees_with_itself() {
        let scene = scene();
        let tracer = crate::trace::SceneTracer::new(&scene);
        let r = validate(&scene, &tracer, &tracer, &ANALYTIC, &options()).unwrap();
        assert!(r.passed(), "{}", r.markdown());
        let a = r.kind(Kind::AnalyticSdf);
        assert_eq!(a.agree, a.rays);
        assert!(a.rays > 1000, "{}", r.markdown());
        assert_eq!(a.dt_max, 0.0);
        assert!(r.shadow.rays > 500);
        assert_eq!(r.shadow.agree, r.shadow.rays);
        assert_eq!(r.pixels.len(), 48 * 36);
    }

    /// A backend that misses everything fails, with the failures in words; a skipped object
    /// fails even when every ray agrees.
    #[test]
    fn failures_are_listed() {
        struct Blind;
        impl RayQuery for Blind {
            fn closest_hit(&self, _: &Ray, _: f32, _: f32) -> Option<QueryHit> {
                None
            }
            fn occluded(&self, _: &Ray, _: f32, _: f32) -> bool {
                false
            }
        }
        let scene = scene();
        let tracer = crate::trace::SceneTracer::new(&scene);
        let r = validate(&scene, &Blind, &tracer, &ANALYTIC, &options()).unwrap();
        assert!(!r.passed());
        let text = r.failures.join("\n");
        assert!(text.contains("analytic SDFs: hit/miss agreement"), "{text}");
        assert!(text.contains("outside the ε band"), "{text}");
        assert!(text.contains("shadow rays"), "{text}");

        let mut checks = ANALYTIC.to_vec();
        checks[1] = SdfCheck::Skipped { why: "test".into() };
        let r = validate(&scene, &tracer, &tracer, &checks, &options()).unwrap();
        assert!(!r.passed());
        assert!(r.failures[0].contains("#1"), "{:?}", r.failures);
        assert!(r.kind(Kind::UncheckedSdf).rays > 0);
        assert!(r.markdown().contains("SKIPPED: test"));
    }

    /// Random ray origins lie outside every object, and bad grids are errors.
    #[test]
    fn random_rays_start_outside() {
        let scene = scene();
        let opts = options();
        let p = probes::probes(&scene, &opts).unwrap();
        assert_eq!(p.len(), 48 * 36 + 300);
        let mut regs = Registers::new();
        for probe in &p[48 * 36..] {
            for o in &scene.objects {
                assert!(o.lowered.distance.eval_in(probe.ray.origin, &mut regs) > 0.0);
            }
        }
        let bad = Options { width: 0, ..opts };
        let tracer = crate::trace::SceneTracer::new(&scene);
        assert!(validate(&scene, &tracer, &tracer, &ANALYTIC, &bad).is_err());
        assert!(validate(&scene, &tracer, &tracer, &ANALYTIC[..2], &opts).is_err());
    }
}
