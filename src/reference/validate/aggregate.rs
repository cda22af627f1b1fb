//! The validation's figures: the outcomes of every ray summed per object kind (counts,
//! agreement percentages, |Δt| statistics), the thresholds checked against them, the example
//! rays and the per-pixel classes, gathered into the [`Report`].

use super::SdfCheck;
use super::classify::{Classified, Kind, Outcome, ShadowOutcome};
use super::probes::Options;
use crate::geom::Ray;
use crate::scene::Scene;
use crate::trace::query::{ObjectId, QueryHit};
use serde::Serialize;

/// Least hit/miss agreement on mesh rays.
pub const MESH_AGREEMENT: f64 = 0.9999;
/// Least hit/miss agreement on analytic-SDF and certified-SDF rays.
pub const SDF_AGREEMENT: f64 = 0.999;
/// Least agreement of shadow rays.
pub const SHADOW_AGREEMENT: f64 = 0.999;

/// What the primary ray of one pixel showed (for the mismatch image).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PixelClass {
    /// Both missed.
    Miss,
    /// Both hit within tolerance, and the shadow rays agree; `shade` ∈ 0..=255 is |n·d|.
    Agree {
        /// Grey level for the picture.
        shade: u8,
    },
    /// Only one side hit (or they hit different surfaces), at a silhouette.
    DisagreeInBand,
    /// Only one side hit, away from any silhouette.
    DisagreeElsewhere,
    /// Both hit but |Δt| is over tolerance.
    OverTolerance,
    /// The primary hits agree, a shadow ray from it does not.
    ShadowMismatch,
    /// We hit an object the referee skipped.
    Unchecked,
    /// We hit a clipped unbounded object where the referee has no mesh for it (left out).
    OutsideMesh,
}

/// The figures of one object kind.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct KindStats {
    /// Rays classified under this kind (primary and random).
    pub rays: usize,
    /// Rays on which both sides agree on hit/miss and surface.
    pub agree: usize,
    /// agree / rays, in percent.
    pub agreement_percent: f64,
    /// Rays both hit (the |Δt| sample).
    pub both_hit: usize,
    /// Largest |Δt|.
    pub dt_max: f32,
    /// 99th percentile of |Δt|.
    pub dt_p99: f32,
    /// Largest |Δt| / tolerance.
    pub dt_worst_of_tolerance: f32,
    /// Rays both hit with |Δt| over tolerance.
    pub dt_over_tolerance: usize,
    /// Hit/miss disagreements at silhouettes (the band).
    pub disagree_in_band: usize,
    /// Hit/miss disagreements elsewhere.
    pub disagree_elsewhere: usize,
    /// Shadow rays from hits of this kind.
    pub shadow_rays: usize,
    /// Of which both sides agree.
    pub shadow_agree: usize,
}

/// Shadow-ray figures over all kinds.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ShadowStats {
    /// Shadow rays cast.
    pub rays: usize,
    /// Rays both sides answered alike.
    pub agree: usize,
    /// agree / rays, in percent (100 with no rays).
    pub agreement_percent: f64,
    /// Disagreements where the ray leaves the surface at a grazing angle (|n·l| < GRAZING).
    pub disagree_grazing: usize,
    /// Disagreements elsewhere.
    pub disagree_elsewhere: usize,
    /// Shadow rays left out (not in `rays`): the two sides disagree and the occluder our
    /// tracer finds first is a clipped unbounded meshed object outside the box its mesh covers.
    pub excluded_outside_mesh: usize,
    /// Shadow rays left out (not in `rays`): the two sides disagree on a blocker that is a
    /// meshed object within the mesh's tolerance of the ray — our blocker lies within the
    /// band of the referee's mesh, or the referee's mesh blocks at a point outside the true
    /// solid (field ≥ −3·ε(t)), where the mesh stands proud of the surface by up to τ.
    pub within_mesh_tolerance: usize,
}

/// One SDF object and how the referee checked it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ObjectEntry {
    /// Index into `Scene::objects`.
    pub index: usize,
    /// Name.
    pub name: String,
    /// How it was checked.
    pub check: SdfCheck,
}

/// One row of the per-kind table.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct KindRow {
    /// The kind.
    pub kind: Kind,
    /// Its figures.
    #[serde(flatten)]
    pub stats: KindStats,
}

/// A ray on which the two sides disagree, for reproducing it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Example {
    /// What went wrong.
    pub what: String,
    /// Kind the ray is classified under.
    pub kind: Kind,
    /// Ray origin.
    pub origin: [f32; 3],
    /// Unit ray direction.
    pub direction: [f32; 3],
    /// Our hit: (t, object, |n·d|).
    pub ours: Option<(f32, String, f32)>,
    /// The referee's hit: (t, object, |n·d|).
    pub referee: Option<(f32, String, f32)>,
    /// The camera-grid pixel (column, row) of a camera ray; none for a random ray.
    pub pixel: Option<[u32; 2]>,
}

/// How many disagreeing rays a report keeps as examples.
pub const EXAMPLES: usize = 20;

/// The result of a validation.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report {
    /// The scene's name.
    pub scene: String,
    /// Camera rays: width.
    pub width: u32,
    /// Camera rays: height.
    pub height: u32,
    /// Random rays cast.
    pub random_rays: usize,
    /// Their seed.
    pub seed: u64,
    /// Diameter of the scene's finite bounds (the mesh |Δt| scale).
    pub diameter: f32,
    /// The mesh |Δt| tolerance, 1e-4 × diameter.
    pub mesh_dt_tolerance: f32,
    /// SDF objects and how each was checked.
    pub objects: Vec<ObjectEntry>,
    /// Mesh instances (each checked as Embree triangles).
    pub mesh_instances: usize,
    /// Triangles placed.
    pub mesh_triangles: usize,
    /// Rays both sides missed.
    pub both_miss: usize,
    /// Rays left out of every figure: our tracer hit a clipped unbounded meshed object outside
    /// the box its mesh covers (shrunk by the mesher's tolerance), and the referee has no
    /// surface before that hit.
    pub excluded_outside_mesh: usize,
    /// Certified root searches that ran out of interval evaluations (their queries were
    /// answered "no hit" by that object, which is not a certified answer).
    pub uncertified_searches: u64,
    /// Per kind, the kinds that occurred (every kind in [`Kind::ALL`] order, rows with no ray
    /// left out).
    pub kinds: Vec<KindRow>,
    /// Shadow rays over all kinds.
    pub shadow: ShadowStats,
    /// Every threshold that failed, in words (empty when the validation passed).
    pub failures: Vec<String>,
    /// The first disagreeing rays (hit/miss outside the band, then |Δt| over tolerance, then
    /// in the band), at most [`EXAMPLES`].
    pub examples: Vec<Example>,
    /// Per pixel of the camera grid, row-major: what its ray showed.
    #[serde(skip)]
    pub pixels: Vec<PixelClass>,
}

impl Report {
    /// Whether every threshold holds and every object was checked.
    pub fn passed(&self) -> bool {
        self.failures.is_empty()
    }

    /// Records `n` certified root searches that ran out of interval evaluations during the
    /// validation. Each may have answered a query wrongly, so they fail the validation when
    /// they exceed the share of disagreements [`SDF_AGREEMENT`] allows among the certified
    /// and shadow rays.
    pub fn note_uncertified(&mut self, n: u64) {
        self.uncertified_searches = n;
        let rays = self.kind(Kind::CertifiedSdf).rays + self.shadow.rays;
        if n as f64 > (1.0 - SDF_AGREEMENT) * rays as f64 {
            self.failures.push(format!(
                "certified SDFs: {n} root searches ran out of interval evaluations, more than \
                 {:.1}% of the {rays} certified-SDF and shadow rays",
                100.0 * (1.0 - SDF_AGREEMENT)
            ));
        }
    }

    /// The figures of one kind (zeros when no ray met it).
    pub fn kind(&self, kind: Kind) -> KindStats {
        self.kinds
            .iter()
            .find(|r| r.kind == kind)
            .map(|r| r.stats.clone())
            .unwrap_or_default()
    }
}

/// The report of the rays `rays` and the shadow rays `shadows` (each with the camera-grid
/// pixel whose hit it leaves) cast on `scene` with `options`; `checks[i]` says how the referee
/// represents SDF object i, `diameter` is the scene's and `mesh_tol` the mesh |Δt| tolerance.
pub(super) fn report(
    scene: &Scene,
    checks: &[SdfCheck],
    options: &Options,
    diameter: f32,
    mesh_tol: f32,
    rays: &[Classified],
    shadows: &[(usize, ShadowOutcome)],
) -> Report {
    let mut stats: [KindStats; 5] = Default::default();
    let mut dts: [Vec<f32>; 5] = Default::default();
    let mut both_miss = 0;
    let mut excluded_outside_mesh = 0;
    let mut pixels = vec![PixelClass::Miss; (options.width * options.height) as usize];
    let examples = examples(scene, options, rays);
    for ray in rays {
        let class = match ray.outcome {
            Outcome::BothMiss => {
                both_miss += 1;
                PixelClass::Miss
            }
            Outcome::Agree { kind, dt, tol } => {
                let k = &mut stats[kind.index()];
                k.rays += 1;
                k.agree += 1;
                k.both_hit += 1;
                dts[kind.index()].push(dt);
                k.dt_worst_of_tolerance = k.dt_worst_of_tolerance.max(dt / tol);
                if dt > tol {
                    k.dt_over_tolerance += 1;
                    PixelClass::OverTolerance
                } else {
                    let cos = ray
                        .referee
                        .map_or(0.0, |h| h.normal.dot(ray.probe.ray.direction).abs());
                    PixelClass::Agree {
                        shade: (40.0 + 200.0 * cos.clamp(0.0, 1.0)) as u8,
                    }
                }
            }
            Outcome::Disagree { kind, in_band } => {
                let k = &mut stats[kind.index()];
                k.rays += 1;
                if in_band {
                    k.disagree_in_band += 1;
                    PixelClass::DisagreeInBand
                } else {
                    k.disagree_elsewhere += 1;
                    PixelClass::DisagreeElsewhere
                }
            }
            Outcome::Unchecked => {
                stats[Kind::UncheckedSdf.index()].rays += 1;
                PixelClass::Unchecked
            }
            Outcome::OutsideMesh => {
                excluded_outside_mesh += 1;
                PixelClass::OutsideMesh
            }
        };
        if let Some(i) = ray.probe.pixel {
            pixels[i] = class;
        }
    }
    let mut shadow = ShadowStats::default();
    for (pixel, s) in shadows {
        if s.outside_mesh {
            shadow.excluded_outside_mesh += 1;
            continue;
        }
        if s.within_mesh_tolerance {
            shadow.within_mesh_tolerance += 1;
            continue;
        }
        shadow.rays += 1;
        let k = &mut stats[s.kind.index()];
        k.shadow_rays += 1;
        if s.agree {
            shadow.agree += 1;
            k.shadow_agree += 1;
        } else {
            if s.grazing {
                shadow.disagree_grazing += 1;
            } else {
                shadow.disagree_elsewhere += 1;
            }
            if matches!(pixels[*pixel], PixelClass::Agree { .. }) {
                pixels[*pixel] = PixelClass::ShadowMismatch;
            }
        }
    }
    shadow.agreement_percent = percent(shadow.agree, shadow.rays);
    for (k, d) in stats.iter_mut().zip(dts.iter_mut()) {
        k.agreement_percent = percent(k.agree, k.rays);
        d.sort_by(f32::total_cmp);
        k.dt_max = d.last().copied().unwrap_or(0.0);
        k.dt_p99 = if d.is_empty() {
            0.0
        } else {
            d[((d.len() - 1) as f64 * 0.99).round() as usize]
        };
    }

    let objects: Vec<ObjectEntry> = scene
        .objects
        .iter()
        .zip(checks)
        .enumerate()
        .map(|(index, (o, c))| ObjectEntry {
            index,
            name: o.label(),
            check: c.clone(),
        })
        .collect();
    let failures = failures(&objects, &stats, &shadow, mesh_tol);
    let kinds = Kind::ALL
        .iter()
        .zip(stats)
        .filter(|(_, s)| s.rays > 0 || s.shadow_rays > 0)
        .map(|(&kind, stats)| KindRow { kind, stats })
        .collect();
    Report {
        scene: scene.source_name.clone(),
        width: options.width,
        height: options.height,
        random_rays: options.random,
        seed: options.seed,
        diameter,
        mesh_dt_tolerance: mesh_tol,
        objects,
        mesh_instances: scene.meshes.instances.len(),
        mesh_triangles: scene.meshes.triangle_count(),
        both_miss,
        excluded_outside_mesh,
        uncertified_searches: 0,
        kinds,
        shadow,
        failures,
        examples,
        pixels,
    }
}

/// The first disagreeing rays, at most [`EXAMPLES`]: hit/miss outside the band first, then
/// |Δt| over tolerance, then hit/miss in the band.
fn examples(scene: &Scene, options: &Options, rays: &[Classified]) -> Vec<Example> {
    let describe = |h: &Option<QueryHit>, ray: &Ray| {
        h.map(|h| {
            let object = match h.object {
                ObjectId::Sdf(i) => format!("SDF #{i} `{}`", scene.objects[i].label()),
                ObjectId::MeshInstance(k) => format!(
                    "mesh instance #{k} `{}`",
                    scene
                        .meshes
                        .instances
                        .get(k)
                        .map_or("", |m| m.name.as_str())
                ),
            };
            (h.t, object, h.normal.dot(ray.direction).abs())
        })
    };
    let mut examples: [Vec<Example>; 3] = Default::default();
    for ray in rays {
        let (what, rank, kind) = match ray.outcome {
            Outcome::Disagree {
                kind,
                in_band: false,
            } => ("hit/miss disagreement away from silhouettes", 0, kind),
            Outcome::Agree { kind, dt, tol } if dt > tol => ("|Δt| over tolerance", 1, kind),
            Outcome::Disagree {
                kind,
                in_band: true,
            } => ("hit/miss disagreement at a silhouette", 2, kind),
            _ => ("", 3, Kind::Mesh),
        };
        let probe = &ray.probe;
        if rank < 3 && examples[rank].len() < EXAMPLES {
            examples[rank].push(Example {
                what: what.into(),
                kind,
                origin: probe.ray.origin.to_array(),
                direction: probe.ray.direction.to_array(),
                ours: describe(&ray.ours, &probe.ray),
                referee: describe(&ray.referee, &probe.ray),
                pixel: probe
                    .pixel
                    .map(|i| [i as u32 % options.width, i as u32 / options.width]),
            });
        }
    }
    examples.into_iter().flatten().take(EXAMPLES).collect()
}

fn percent(part: usize, whole: usize) -> f64 {
    if whole == 0 {
        100.0
    } else {
        100.0 * part as f64 / whole as f64
    }
}

/// Every threshold that fails, in words.
fn failures(
    objects: &[ObjectEntry],
    stats: &[KindStats; 5],
    shadow: &ShadowStats,
    mesh_tol: f32,
) -> Vec<String> {
    let mut out = Vec::new();
    for o in objects {
        if let SdfCheck::Skipped { why } = &o.check {
            out.push(format!(
                "SDF object #{} `{}` is not checked by the referee: {why}",
                o.index, o.name
            ));
        }
    }
    let disagreements = |k: &KindStats| {
        format!(
            "{} of {} rays disagree: {} at silhouettes, {} elsewhere",
            k.rays - k.agree,
            k.rays,
            k.disagree_in_band,
            k.disagree_elsewhere
        )
    };
    let mesh = &stats[Kind::Mesh.index()];
    if mesh.rays > 0 && mesh.agreement_percent < 100.0 * MESH_AGREEMENT {
        out.push(format!(
            "meshes: hit/miss agreement {:.4}% < {:.2}% ({})",
            mesh.agreement_percent,
            100.0 * MESH_AGREEMENT,
            disagreements(mesh)
        ));
    }
    if mesh.dt_over_tolerance > 0 {
        out.push(format!(
            "meshes: {} hits with |Δt| over 1e-4 × scene diameter = {mesh_tol:.3e} (max {:.3e})",
            mesh.dt_over_tolerance, mesh.dt_max
        ));
    }
    // The SDF kinds: where a disagreement is excused, and the |Δt| tolerance, in words.
    for (kind, name, band, tolerance) in [
        (
            Kind::AnalyticSdf,
            "analytic SDFs",
            "the ε band at silhouettes",
            "max(10·ε(t), 2·ε(t)/|n·d|)",
        ),
        (
            Kind::CertifiedSdf,
            "certified SDFs",
            "the ε band (field within ε(t) at our near miss, or a crossing at most ε(t)/2 deep)",
            "max(10·ε(t), (2·ε(t) + δ)/|n·d|)",
        ),
        (
            Kind::MeshedSdf,
            "meshed SDFs",
            "the mesher's tolerance band",
            "(tolerance + 2·ε(t))/|n·d|",
        ),
    ] {
        let k = &stats[kind.index()];
        // Meshed SDFs have no agreement threshold: their disagreements all lie in the band.
        if kind != Kind::MeshedSdf && k.rays > 0 && k.agreement_percent < 100.0 * SDF_AGREEMENT {
            out.push(format!(
                "{name}: hit/miss agreement {:.4}% < {:.1}% ({})",
                k.agreement_percent,
                100.0 * SDF_AGREEMENT,
                disagreements(k)
            ));
        }
        if k.disagree_elsewhere > 0 {
            out.push(format!(
                "{name}: {} hit/miss disagreements outside {band}",
                k.disagree_elsewhere
            ));
        }
        if k.dt_over_tolerance > 0 {
            out.push(format!(
                "{name}: {} hits with |Δt| over {tolerance} (worst {:.2}× the tolerance, max \
                 |Δt| {:.3e})",
                k.dt_over_tolerance, k.dt_worst_of_tolerance, k.dt_max
            ));
        }
    }
    if shadow.agreement_percent < 100.0 * SHADOW_AGREEMENT {
        out.push(format!(
            "shadow rays: agreement {:.4}% < {:.1}% ({} of {} disagree: {} at grazing angles, \
             {} elsewhere)",
            shadow.agreement_percent,
            100.0 * SHADOW_AGREEMENT,
            shadow.rays - shadow.agree,
            shadow.rays,
            shadow.disagree_grazing,
            shadow.disagree_elsewhere
        ));
    }
    out
}
