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

pub use super::check::SdfCheck;
use crate::accel::field::FieldCursor;
use crate::geom::{Aabb, Ray};
use crate::rng::Rng;
use crate::scene::{Light, Scene};
use crate::sdf::tape::Registers;
use crate::shade::offset_from_surface;
use crate::trace::epsilon_at;
use crate::trace::query::{ObjectId, QueryHit, RayQuery};
use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;
use std::fmt::Write as _;

/// Below this |n·d| a ray grazes a surface: a hit/miss disagreement there is at a silhouette.
pub const GRAZING: f32 = 0.05;
/// Least hit/miss agreement on mesh rays.
pub const MESH_AGREEMENT: f64 = 0.9999;
/// Largest mesh |Δt| as a fraction of the scene's diameter.
pub const MESH_DT_OF_DIAMETER: f32 = 1e-4;
/// Least hit/miss agreement on analytic-SDF rays.
pub const SDF_AGREEMENT: f64 = 0.999;

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
/// Least agreement of shadow rays.
pub const SHADOW_AGREEMENT: f64 = 0.999;

/// The kind of object a ray is classified by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    /// A triangle-mesh instance.
    Mesh,
    /// An SDF object the referee intersects in closed form.
    AnalyticSdf,
    /// An SDF object the referee intersects as an extracted mesh.
    MeshedSdf,
    /// An SDF object the referee skipped (only our side can hit it).
    UncheckedSdf,
}

impl Kind {
    /// Every kind, in table order.
    pub const ALL: [Kind; 4] = [
        Kind::Mesh,
        Kind::AnalyticSdf,
        Kind::MeshedSdf,
        Kind::UncheckedSdf,
    ];

    /// The name in tables.
    pub fn label(self) -> &'static str {
        match self {
            Kind::Mesh => "mesh",
            Kind::AnalyticSdf => "analytic SDF",
            Kind::MeshedSdf => "meshed SDF",
            Kind::UncheckedSdf => "unchecked SDF",
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// Which rays to cast.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    /// Camera rays: one through every pixel centre of a width × height image.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// Random rays through the scene's bounds.
    pub random: usize,
    /// Seed of the random rays.
    pub seed: u64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            width: 320,
            height: 240,
            random: 10_000,
            seed: 1,
        }
    }
}

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

impl PixelClass {
    /// Every class that has a fixed colour, in legend order.
    pub const LEGEND: [PixelClass; 7] = [
        PixelClass::Miss,
        PixelClass::DisagreeInBand,
        PixelClass::DisagreeElsewhere,
        PixelClass::OverTolerance,
        PixelClass::ShadowMismatch,
        PixelClass::Unchecked,
        PixelClass::OutsideMesh,
    ];

    /// Its colour in the mismatch image: agreeing hits in grey (brighter where the ray meets
    /// the surface head-on), misses dark blue, silhouette disagreements yellow, other
    /// disagreements red, |Δt| over tolerance magenta, shadow mismatches cyan, unchecked
    /// objects green, hits beyond a clipped object's mesh dark purple.
    pub fn colour(self) -> [u8; 3] {
        match self {
            PixelClass::Miss => [20, 24, 48],
            PixelClass::Agree { shade } => [shade, shade, shade],
            PixelClass::DisagreeInBand => [255, 200, 0],
            PixelClass::DisagreeElsewhere => [255, 0, 0],
            PixelClass::OverTolerance => [255, 0, 255],
            PixelClass::ShadowMismatch => [0, 200, 255],
            PixelClass::Unchecked => [0, 170, 0],
            PixelClass::OutsideMesh => [70, 40, 90],
        }
    }

    /// What the colour means.
    pub fn meaning(self) -> &'static str {
        match self {
            PixelClass::Miss => "both miss",
            PixelClass::Agree { .. } => "both hit, agree (grey = |n.d|)",
            PixelClass::DisagreeInBand => "hit/miss mismatch at a silhouette",
            PixelClass::DisagreeElsewhere => "hit/miss mismatch elsewhere",
            PixelClass::OverTolerance => "|dt| over tolerance",
            PixelClass::ShadowMismatch => "shadow-ray mismatch",
            PixelClass::Unchecked => "object the referee skipped",
            PixelClass::OutsideMesh => "beyond a clipped object's mesh (left out)",
        }
    }

    /// Whether two classes share a legend entry.
    pub fn same_entry(self, other: PixelClass) -> bool {
        std::mem::discriminant(&self) == std::mem::discriminant(&other)
    }
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

    /// The figures of one kind (zeros when no ray met it).
    pub fn kind(&self, kind: Kind) -> KindStats {
        self.kinds
            .iter()
            .find(|r| r.kind == kind)
            .map(|r| r.stats.clone())
            .unwrap_or_default()
    }

    /// The camera grid's pixels coloured by [`PixelClass::colour`] (no legend).
    pub fn mismatch_image(&self) -> image::RgbImage {
        image::RgbImage::from_fn(self.width, self.height, |x, y| {
            image::Rgb(self.pixels[(y * self.width + x) as usize].colour())
        })
    }

    /// The mismatch image's legend: each colour, what it means and how many pixels have it
    /// (agreeing hits as one entry, shown in a mid grey).
    pub fn legend(&self) -> Vec<([u8; 3], String)> {
        std::iter::once((
            PixelClass::Agree { shade: 170 },
            PixelClass::Agree { shade: 0 },
        ))
        .map(|(shown, class)| (shown.colour(), class))
        .chain(PixelClass::LEGEND.iter().map(|&c| (c.colour(), c)))
        .map(|(colour, class)| {
            let n = self.pixels.iter().filter(|p| p.same_entry(class)).count();
            (colour, format!("{} ({n} px)", class.meaning()))
        })
        .collect()
    }

    /// The report as a page to browse ([`crate::render::report`]): the mismatch image with
    /// its legend, the per-kind and shadow figures, the objects, the verdict, the disagreeing
    /// pixels and example rays, each a link to its pixel. `seconds` is the run's time.
    pub fn page(&self, seconds: f64) -> anyhow::Result<crate::render::report::Report> {
        use crate::render::report::{
            Legend, Picture, PixelLink, PixelList, Report as Page, Row, Table,
        };
        /// Most disagreeing pixels listed.
        const LISTED: usize = 500;
        let cells = |v: Vec<String>| Row {
            cells: v,
            ..Default::default()
        };
        let mut kinds: Vec<Row> = self.kinds.iter().map(|r| cells(kind_cells(r))).collect();
        let blank = |label: &str, n: usize| {
            let mut v = vec![label.to_string(), n.to_string()];
            v.resize(11, String::new());
            cells(v)
        };
        kinds.push(blank("(both miss)", self.both_miss));
        if self.excluded_outside_mesh > 0 {
            kinds.push(blank(
                "(left out: our hit beyond a clipped object's mesh)",
                self.excluded_outside_mesh,
            ));
        }
        let sh = &self.shadow;
        let shadow = vec![
            cells(vec!["cast".into(), sh.rays.to_string()]),
            cells(vec![
                "agree".into(),
                format!("{:.3}%", sh.agreement_percent),
            ]),
            cells(vec![
                "disagree at grazing angles".into(),
                sh.disagree_grazing.to_string(),
            ]),
            cells(vec![
                "disagree elsewhere".into(),
                sh.disagree_elsewhere.to_string(),
            ]),
            cells(vec![
                "left out: our occluder beyond a clipped object's mesh".into(),
                sh.excluded_outside_mesh.to_string(),
            ]),
            cells(vec![
                "left out: meshed blocker within the mesh's tolerance".into(),
                sh.within_mesh_tolerance.to_string(),
            ]),
        ];
        let mut objects = Vec::new();
        if self.mesh_instances > 0 {
            objects.push(cells(vec![
                format!("{} mesh instance(s)", self.mesh_instances),
                format!(
                    "{} triangles: Embree triangle geometry (instanced)",
                    self.mesh_triangles
                ),
            ]));
        }
        for o in &self.objects {
            objects.push(cells(vec![
                format!("SDF #{} `{}`", o.index, o.name),
                o.check.describe(),
            ]));
        }
        let verdict: Vec<Row> = if self.passed() {
            vec![cells(vec!["PASSED: every threshold holds".into()])]
        } else {
            self.failures
                .iter()
                .map(|f| Row {
                    cells: vec![f.clone()],
                    failed: true,
                    ..Default::default()
                })
                .collect()
        };
        let hit = |h: &Option<(f32, String, f32)>| {
            h.as_ref().map_or("miss".to_string(), |(t, o, c)| {
                format!("t {t:.5} on {o}, |n·d| {c:.3}")
            })
        };
        let examples = PixelList {
            heading: "Disagreeing camera rays, with both answers".into(),
            image: 0,
            total: self.examples.iter().filter(|e| e.pixel.is_some()).count(),
            pixels: self
                .examples
                .iter()
                .filter_map(|e| {
                    let [x, y] = e.pixel?;
                    Some(PixelLink {
                        x,
                        y,
                        label: format!(
                            "{} [{}]: ours {} | referee {}",
                            e.what,
                            e.kind.label(),
                            hit(&e.ours),
                            hit(&e.referee)
                        ),
                    })
                })
                .collect(),
        };
        let disagreeing: Vec<(usize, PixelClass)> = self
            .pixels
            .iter()
            .copied()
            .enumerate()
            .filter(|(_, c)| !matches!(c, PixelClass::Agree { .. } | PixelClass::Miss))
            .collect();
        let pixels = PixelList {
            heading: "Pixels whose rays disagree (click one to see it)".into(),
            image: 0,
            total: disagreeing.len(),
            pixels: disagreeing
                .iter()
                .take(LISTED)
                .map(|&(i, c)| PixelLink {
                    x: i as u32 % self.width,
                    y: i as u32 / self.width,
                    label: c.meaning().into(),
                })
                .collect(),
        };
        let header = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        Ok(Page {
            title: format!("hytrace validate: {}", self.scene),
            facts: vec![
                ("scene".into(), self.scene.clone()),
                (
                    "camera rays".into(),
                    format!("{}×{} (one per pixel)", self.width, self.height),
                ),
                (
                    "random rays".into(),
                    format!("{} (seed {})", self.random_rays, self.seed),
                ),
                ("scene diameter".into(), format!("{:.4}", self.diameter)),
                ("time".into(), format!("{seconds:.2} s")),
                (
                    "verdict".into(),
                    if self.passed() {
                        "PASSED".into()
                    } else {
                        format!("FAILED ({} threshold(s))", self.failures.len())
                    },
                ),
            ],
            images: vec![Picture::new(
                "mismatch",
                "what each camera ray showed (legend below)",
                &self.mismatch_image(),
            )?],
            initial: (0, 0),
            tables: vec![
                Table {
                    heading: "Verdict".into(),
                    header: header(&["threshold"]),
                    rows: verdict,
                },
                Table {
                    heading: "Rays per object kind".into(),
                    header: header(&[
                        "kind",
                        "rays",
                        "hit/miss agree",
                        "max |Δt|",
                        "p99 |Δt|",
                        "worst |Δt|/tol",
                        "|Δt| over tol",
                        "disagree in band",
                        "disagree elsewhere",
                        "shadow rays",
                        "shadow agree",
                    ]),
                    rows: kinds,
                },
                Table {
                    heading: "Shadow rays".into(),
                    header: header(&["", "rays"]),
                    rows: shadow,
                },
                Table {
                    heading: "Objects".into(),
                    header: header(&["object", "checked as"]),
                    rows: objects,
                },
            ],
            legends: vec![Legend {
                heading: "Mismatch image".into(),
                entries: self.legend(),
            }],
            pixel_lists: vec![examples, pixels],
            notes: Vec::new(),
        })
    }

    /// The report as Markdown: the per-kind table, shadow rays, the objects, the verdict.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "### `validate` {}: {}×{} camera rays + {} random rays (seed {}), scene diameter {:.4}\n",
            self.scene, self.width, self.height, self.random_rays, self.seed, self.diameter
        );
        s += "| kind | rays | hit/miss agree | max \\|Δt\\| | p99 \\|Δt\\| | worst \\|Δt\\|/tol | \\|Δt\\| over tol | disagree in band | disagree elsewhere | shadow rays | shadow agree |\n";
        s += "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
        for row in &self.kinds {
            let _ = writeln!(s, "| {} |", kind_cells(row).join(" | "));
        }
        let _ = writeln!(s, "| (both miss) | {} | | | | | | | | | |", self.both_miss);
        if self.excluded_outside_mesh > 0 {
            let _ = writeln!(
                s,
                "| (left out: our hit beyond a clipped object's mesh) | {} | | | | | | | | | |",
                self.excluded_outside_mesh
            );
        }
        let sh = &self.shadow;
        let _ = writeln!(
            s,
            "\nShadow rays: {} cast, {:.3}% agree ({} disagreements at grazing angles, {} elsewhere); \
             left out: {} whose occluder (ours) lies beyond a clipped object's mesh, {} whose \
             meshed blocker lies within the mesh's tolerance of the ray.",
            sh.rays,
            sh.agreement_percent,
            sh.disagree_grazing,
            sh.disagree_elsewhere,
            sh.excluded_outside_mesh,
            sh.within_mesh_tolerance
        );
        s += "\nObjects:\n\n";
        if self.mesh_instances > 0 {
            let _ = writeln!(
                s,
                "- {} mesh instance(s), {} triangles: Embree triangle geometry (instanced)",
                self.mesh_instances, self.mesh_triangles
            );
        }
        for o in &self.objects {
            let _ = writeln!(s, "- SDF #{} `{}`: {}", o.index, o.name, o.check.describe());
        }
        if self.passed() {
            s += "\n**PASSED**: every threshold holds.\n";
        } else {
            s += "\n**FAILED**:\n\n";
            for f in &self.failures {
                let _ = writeln!(s, "- {f}");
            }
        }
        if !self.examples.is_empty() {
            s += "\nDisagreeing rays (origin → direction: ours | referee as (t, object, |n·d|)):\n\n";
            for e in &self.examples {
                let hit = |h: &Option<(f32, String, f32)>| {
                    h.as_ref().map_or("miss".to_string(), |(t, o, c)| {
                        format!("({t:.5}, {o}, {c:.3})")
                    })
                };
                let _ = writeln!(
                    s,
                    "- {} [{}]: {:?} → {:?}: {} | {}",
                    e.what,
                    e.kind.label(),
                    e.origin,
                    e.direction,
                    hit(&e.ours),
                    hit(&e.referee)
                );
            }
        }
        s
    }
}

/// One kind's figures as the cells of its table row (Markdown and the report page): kind,
/// rays, agreement, max and p99 |Δt|, worst |Δt|/tolerance, over tolerance, disagreements in
/// the band and elsewhere, shadow rays and their agreement.
fn kind_cells(row: &KindRow) -> Vec<String> {
    let k = &row.stats;
    let shadow = if k.shadow_rays == 0 {
        "—".to_string()
    } else {
        format!(
            "{:.3}%",
            100.0 * k.shadow_agree as f64 / k.shadow_rays as f64
        )
    };
    let checked = row.kind != Kind::UncheckedSdf;
    let or_dash = |v: String| if checked { v } else { "—".into() };
    vec![
        row.kind.label().into(),
        k.rays.to_string(),
        if checked {
            format!("{:.3}%", k.agreement_percent)
        } else {
            "not checked".into()
        },
        or_dash(format!("{:.2e}", k.dt_max)),
        or_dash(format!("{:.2e}", k.dt_p99)),
        or_dash(format!("{:.3}", k.dt_worst_of_tolerance)),
        or_dash(k.dt_over_tolerance.to_string()),
        or_dash(k.disagree_in_band.to_string()),
        or_dash(k.disagree_elsewhere.to_string()),
        k.shadow_rays.to_string(),
        shadow,
    ]
}

/// One ray to compare: the ray, and the pixel it belongs to (camera rays).
#[derive(Debug, Clone, Copy)]
struct Probe {
    ray: Ray,
    pixel: Option<usize>,
}

/// The outcome of one ray.
#[derive(Debug, Clone, Copy)]
enum Outcome {
    BothMiss,
    Agree { kind: Kind, dt: f32, tol: f32 },
    Disagree { kind: Kind, in_band: bool },
    Unchecked,
    OutsideMesh,
}

/// A shadow ray's outcome: the kind of the hit it leaves, whether both agree, whether it
/// leaves at a grazing angle.
#[derive(Debug, Clone, Copy)]
struct ShadowOutcome {
    kind: Kind,
    agree: bool,
    grazing: bool,
    outside_mesh: bool,
    within_mesh_tolerance: bool,
}

/// The finite bounds of the scene (SDF objects and meshes); around the camera when nothing is
/// finite (a scene of planes), so random rays still have somewhere to go.
pub fn scene_bounds(scene: &Scene) -> Aabb {
    let b = scene.finite_bounds().union(&scene.meshes.bounds());
    if b.is_empty() || !b.is_finite() {
        let c = scene.camera.position;
        Aabb::new(c, c).expand(1.0)
    } else {
        b
    }
}

/// Every pixel's camera ray, then `random` rays from a sphere around the bounds (1.5 × their
/// half-diagonal) toward uniform points inside them. Origins inside an SDF solid (below a ground
/// plane, say) are drawn again: there the sphere tracer reports a hit at t = 0 and a
/// closed-form referee the surface crossing, a known, intended difference.
fn probes(scene: &Scene, options: &Options) -> Result<Vec<Probe>, String> {
    let (w, h) = (options.width, options.height);
    let aspect = w as f32 / h as f32;
    let mut out = Vec::with_capacity((w * h) as usize + options.random);
    for y in 0..h {
        for x in 0..w {
            let (u, v) = ((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
            out.push(Probe {
                ray: scene.camera.ray(u, v, aspect),
                pixel: Some((y * w + x) as usize),
            });
        }
    }
    let b = scene_bounds(scene);
    let (c, r) = (b.center(), 0.5 * b.diagonal().max(1e-6));
    let clearance = 4.0 * epsilon_at(&scene.tracer, 0.0);
    let mut regs = Registers::new();
    let outside = |p: Vec3, regs: &mut Registers| {
        scene
            .objects
            .iter()
            .all(|o| o.lowered.distance.eval_in(p, regs) > clearance)
    };
    let mut rng = Rng::new(options.seed);
    let mut attempts = 0usize;
    let budget = 1000 * options.random.max(1);
    for _ in 0..options.random {
        let o = loop {
            attempts += 1;
            if attempts > budget {
                return Err(format!(
                    "could not find {} random ray origins outside every object on the sphere of \
                     radius {:.4} around the scene's bounds",
                    options.random,
                    1.5 * r
                ));
            }
            let o = c + 1.5 * r * rng.direction();
            if outside(o, &mut regs) {
                break o;
            }
        };
        let target = rng.in_box(b.min, b.max);
        if (target - o).length_squared() > 0.0 {
            out.push(Probe {
                ray: Ray::new(o, target - o),
                pixel: None,
            });
        }
    }
    Ok(out)
}

/// Validates `ours` against `referee` on `scene`: `checks[i]` says how the referee represents
/// SDF object i. Rays are cast in parallel (rayon); the result does not depend on the thread
/// count. Fails only when the rays cannot be generated.
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
    let settings = &scene.tracer;
    let diameter = scene_bounds(scene).diagonal();
    let mesh_tol = mesh_dt_tolerance(diameter);
    let tmax = settings.max_distance;
    let kind_of = |object: ObjectId| match object {
        ObjectId::MeshInstance(_) => Kind::Mesh,
        ObjectId::Sdf(i) => match checks.get(i) {
            Some(SdfCheck::Analytic) => Kind::AnalyticSdf,
            Some(SdfCheck::Meshed { .. }) => Kind::MeshedSdf,
            _ => Kind::UncheckedSdf,
        },
    };
    let meshed_tolerance = |object: ObjectId| match object {
        ObjectId::Sdf(i) => match checks.get(i) {
            Some(SdfCheck::Meshed { tolerance, .. }) => *tolerance,
            _ => 0.0,
        },
        ObjectId::MeshInstance(_) => 0.0,
    };
    let meshed_cell = |object: ObjectId| match object {
        ObjectId::Sdf(i) => match checks.get(i) {
            Some(SdfCheck::Meshed { cell, .. }) => *cell,
            _ => 0.0,
        },
        ObjectId::MeshInstance(_) => 0.0,
    };
    // Where a clipped unbounded meshed object's mesh stands for it: its box, shrunk by the
    // tolerance (a hit that close to the box's faces may belong to a cut-off triangle).
    let mesh_box = |object: ObjectId| match object {
        ObjectId::Sdf(i) => match checks.get(i) {
            Some(SdfCheck::Meshed {
                clipped_to: Some([lo, hi]),
                tolerance,
                ..
            }) => Some((Aabb::new(Vec3::from(*lo), Vec3::from(*hi)), *tolerance)),
            _ => None,
        },
        ObjectId::MeshInstance(_) => None,
    };
    let outside_mesh = |hit: &QueryHit, ray: &Ray| {
        mesh_box(hit.object).is_some_and(|(b, tol)| b.signed_distance(ray.at(hit.t)) > -tol)
    };
    // The |Δt| tolerance at the referee's hit (see the module documentation).
    let tolerance = |hit: &QueryHit, ray: &Ray| {
        let cos = hit.normal.dot(ray.direction).abs();
        match kind_of(hit.object) {
            Kind::Mesh => mesh_tol,
            Kind::AnalyticSdf => sdf_dt_tolerance(settings, hit.t, cos, 0.0),
            Kind::MeshedSdf => sdf_dt_tolerance(settings, hit.t, cos, meshed_tolerance(hit.object)),
            Kind::UncheckedSdf => f32::INFINITY,
        }
    };
    // Half-width of the band around a surface in which a hit/miss disagreement is excused.
    let band = |hit: &QueryHit| {
        let e = epsilon_at(settings, hit.t);
        match kind_of(hit.object) {
            Kind::Mesh => 0.0,
            Kind::AnalyticSdf | Kind::UncheckedSdf => 3.0 * e,
            Kind::MeshedSdf => meshed_tolerance(hit.object) + 3.0 * e,
        }
    };
    let grazing = |hit: &QueryHit, ray: &Ray| hit.normal.dot(ray.direction).abs() < GRAZING;
    // Whether `other` has a surface within the band of `hit`: a probe along the normal through
    // the hit point, from one band-width outside to one band-width inside.
    let near = |other: &dyn Fn(&Ray, f32) -> bool, hit: &QueryHit, ray: &Ray| {
        if kind_of(hit.object) == Kind::Mesh {
            // Both sides intersect the same triangles exactly: only grazing rays are excused.
            return false;
        }
        let w = band(hit);
        let n = hit.normal.normalize_or_zero();
        if n == Vec3::ZERO {
            return false;
        }
        let p = ray.at(hit.t);
        if other(&Ray::new(p + w * n, -n), 2.0 * w) {
            return true;
        }
        // A meshed hit's facet normal is not the surface's: probe along the field's gradient
        // at the hit point too (the direction to the nearest true surface).
        if let ObjectId::Sdf(i) = hit.object
            && kind_of(hit.object) == Kind::MeshedSdf
        {
            let s = settings;
            let g = crate::trace::normal::estimate(
                &mut FieldCursor::whole(&scene.objects[i].lowered.distance, &mut Registers::new()),
                p,
                crate::trace::normal::step_for(s, hit.t),
                s.normals,
            )
            .0
            .normalize_or_zero();
            if g != Vec3::ZERO && other(&Ray::new(p + w * g, -g), 2.0 * w) {
                return true;
            }
        }
        // A meshed object's tolerance bounds how far the mesh strays from the surface, not the
        // converse: at a sharp edge or a thin rim marching cubes cuts the corner, and the
        // surface there can lie up to a cell diagonal from the mesh in a direction other than
        // its normal (the mesher's docs: features thinner than a cell can be lost). So a
        // meshed object's band is also probed along the three axes and the ray, a cell
        // diagonal (+ 3·ε(t)) each way, and along the four cube diagonals.
        let cell = meshed_cell(hit.object);
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
        .any(|&a| other(&Ray::new(p - w * a, a), 2.0 * w))
    };
    // Our hit on a meshed object where the ray only clips a sliver of the true solid (an edge,
    // a rim, a plate thinner than a cell): the object's field, sampled every quarter cell
    // along the ray past the hit, is outside again within a cell diagonal. Marching cubes may
    // lose such a sliver (the mesher's docs), so the referee's miss is at a silhouette.
    let sliver = |hit: &QueryHit, ray: &Ray| {
        let cell = meshed_cell(hit.object);
        match hit.object {
            ObjectId::Sdf(i) if cell > 0.0 => {
                let field = &scene.objects[i].lowered.distance;
                (1..=7).any(|k| field.eval(ray.at(hit.t + 0.25 * k as f32 * cell)) > 0.0)
            }
            _ => false,
        }
    };
    // A sphere tracer stops up to ε(t)/|n·d| before the surface, so near the end of the ray
    // range it can report a surface that lies just beyond tmax, which the referee (stopping
    // at tmax exactly) does not see. Such a hit agrees when the referee finds the same object
    // within tolerance on the ray extended by that tolerance.
    let beyond_the_end = |x: &QueryHit, ray: &Ray| {
        let cos = x.normal.dot(ray.direction).abs().max(1e-6);
        let reach = sdf_dt_tolerance(settings, x.t, cos, 0.0) + meshed_tolerance(x.object) / cos;
        if x.t + reach <= tmax {
            return None;
        }
        let y = referee.closest_hit(ray, 0.0, x.t + reach)?;
        (y.object == x.object && y.t > tmax && (x.t - y.t).abs() <= tolerance(&y, ray)).then_some(y)
    };
    let ours_occ = |r: &Ray, len: f32| ours.occluded(r, 0.0, len);
    let ref_occ = |r: &Ray, len: f32| referee.occluded(r, 0.0, len);

    let probes = probes(scene, options)?;
    let results: Vec<(Probe, Option<QueryHit>, Outcome, Option<QueryHit>)> = probes
        .par_iter()
        .map(|probe| {
            let ray = &probe.ray;
            let a = ours.closest_hit(ray, 0.0, tmax);
            let b = referee.closest_hit(ray, 0.0, tmax);
            let outcome = match (&a, &b) {
                (None, None) => Outcome::BothMiss,
                // Our hit lies where the referee has no mesh for the surface, and the referee
                // sees nothing before it: nothing to compare.
                (Some(x), _)
                    if outside_mesh(x, ray) && b.is_none_or(|y| y.t > x.t - tolerance(x, ray)) =>
                {
                    Outcome::OutsideMesh
                }
                (Some(x), Some(y)) => {
                    // τ bounds the mesh's distance from the surface along the surface's normal,
                    // so along the ray it is τ/|n·d|. Near a crease the mesh cuts (an edge of a
                    // twisted box, a rim) the surface has every normal between the two faces',
                    // ours (from the field, one face) and the facet's (the chamfer, between
                    // them): the tolerance takes the more grazing of the two.
                    let tol = if x.object == y.object && kind_of(y.object) == Kind::MeshedSdf {
                        let facet = y.normal.dot(ray.direction).abs();
                        let normal = if x.normal.dot(ray.direction).abs() < facet {
                            x.normal
                        } else {
                            y.normal
                        };
                        tolerance(&QueryHit { normal, ..*y }, ray)
                    } else {
                        tolerance(y, ray)
                    };
                    let dt = (x.t - y.t).abs();
                    if dt > tol && x.t < y.t && (near(&ref_occ, x, ray) || sliver(x, ray)) {
                        // Our hit lies within the band of the referee's surface, which the
                        // ray passes by: a sphere tracer's near miss at a silhouette (it stops
                        // wherever the ray comes within ε(t) of a surface), then the referee
                        // meets the same or another surface farther on.
                        Outcome::Disagree {
                            kind: kind_of(x.object),
                            in_band: true,
                        }
                    } else if dt > tol
                        && x.t > y.t
                        && kind_of(y.object) == Kind::MeshedSdf
                        && near(&ours_occ, y, ray)
                    {
                        // The referee's mesh, standing up to τ proud of the surface, meets a
                        // ray that passes the true surface within the band: our tracer
                        // rightly goes on to a farther surface (of the same object or not).
                        Outcome::Disagree {
                            kind: kind_of(y.object),
                            in_band: true,
                        }
                    } else if x.object != y.object && dt > tol {
                        // Different surfaces: a hit/miss disagreement on the nearer one.
                        if x.t < y.t {
                            only_ours(kind_of(x.object), || {
                                grazing(x, ray) || (near(&ref_occ, x, ray) || sliver(x, ray))
                            })
                        } else {
                            Outcome::Disagree {
                                kind: kind_of(y.object),
                                in_band: grazing(y, ray) || near(&ours_occ, y, ray),
                            }
                        }
                    } else {
                        Outcome::Agree {
                            kind: kind_of(y.object),
                            dt,
                            tol,
                        }
                    }
                }
                (Some(x), None) => match beyond_the_end(x, ray) {
                    Some(y) => Outcome::Agree {
                        kind: kind_of(y.object),
                        dt: (x.t - y.t).abs(),
                        tol: tolerance(&y, ray),
                    },
                    None => only_ours(kind_of(x.object), || {
                        grazing(x, ray) || (near(&ref_occ, x, ray) || sliver(x, ray))
                    }),
                },
                (None, Some(y)) => Outcome::Disagree {
                    kind: kind_of(y.object),
                    in_band: grazing(y, ray) || near(&ours_occ, y, ray),
                },
            };
            (*probe, b, outcome, a)
        })
        .collect();

    // Shadow rays from every camera-ray hit of the referee toward every light, offset from
    // the surface as the renderer offsets them (`shade::surface_offset`), only toward lights
    // in front of the surface (the renderer casts no others). A directional light's ray stops
    // at `tracer.max_distance`, where our tracer stops every ray.
    let shadows: Vec<(usize, ShadowOutcome)> = results
        .par_iter()
        .filter_map(|(probe, b, _, _)| Some((probe.pixel?, probe.ray, (*b)?)))
        .flat_map_iter(|(pixel, ray, hit)| {
            let p = ray.at(hit.t);
            let n = if hit.normal.dot(ray.direction) > 0.0 {
                -hit.normal
            } else {
                hit.normal
            };
            // A meshed hit lies up to the mesher's tolerance τ from the true surface, on either
            // side: started from the renderer's offset alone, the shadow ray could begin inside
            // the true solid, where our tracer reports the surface itself as the occluder.
            // From a meshed hit the ray therefore starts 2τ further out (≥ τ off the true
            // surface, ≥ τ off the mesh); both sides trace the same ray.
            let offset =
                offset_from_surface(settings, hit.t, p) + 2.0 * meshed_tolerance(hit.object);
            let origin = p + n * offset;
            let kind = kind_of(hit.object);
            scene.lights.iter().filter_map(move |light| {
                let (l, len) = match *light {
                    Light::Ambient { .. } => return None,
                    Light::Point { position, .. } => {
                        let d = position - p;
                        let dist = d.length();
                        if dist <= 0.0 {
                            return None;
                        }
                        (d / dist, dist - offset)
                    }
                    Light::Directional { direction, .. } => (-direction, tmax),
                };
                let cos = n.dot(l);
                if cos <= 0.0 || len <= 0.0 {
                    return None;
                }
                let shadow = Ray::new(origin, l);
                let ours_occluded = ours.occluded(&shadow, 0.0, len);
                let agree = ours_occluded == referee.occluded(&shadow, 0.0, len);
                // Our occluder is where the referee has no mesh for it: nothing to compare.
                let outside_mesh = !agree
                    && ours_occluded
                    && ours
                        .closest_hit(&shadow, 0.0, len)
                        .is_some_and(|h| outside_mesh(&h, &shadow));
                // The blocker is a meshed object and the ray passes within the mesh's tolerance of
                // it: at that distance the mesh cannot say whether the true surface blocks.
                let within_mesh_tolerance = !agree
                    && !outside_mesh
                    && if ours_occluded {
                        ours.closest_hit(&shadow, 0.0, len).is_some_and(|x| {
                            kind_of(x.object) == Kind::MeshedSdf
                                && (near(&ref_occ, &x, &shadow) || sliver(&x, &shadow))
                        })
                    } else {
                        referee
                            .closest_hit(&shadow, 0.0, len)
                            .is_some_and(|y| match y.object {
                                ObjectId::Sdf(i) if kind_of(y.object) == Kind::MeshedSdf => {
                                    scene.objects[i].lowered.distance.eval(shadow.at(y.t))
                                        >= -3.0 * epsilon_at(settings, y.t)
                                }
                                _ => false,
                            })
                    };
                Some((
                    pixel,
                    ShadowOutcome {
                        kind,
                        agree,
                        grazing: cos < GRAZING,
                        outside_mesh,
                        within_mesh_tolerance,
                    },
                ))
            })
        })
        .collect();

    // Tally.
    let mut stats: [KindStats; 4] = Default::default();
    let mut dts: [Vec<f32>; 4] = Default::default();
    let mut both_miss = 0;
    let mut excluded_outside_mesh = 0;
    let mut pixels = vec![PixelClass::Miss; (options.width * options.height) as usize];
    let describe = |h: &Option<QueryHit>, ray: &Ray| {
        h.map(|h| {
            let object = match h.object {
                ObjectId::Sdf(i) => format!("SDF #{i} `{}`", scene.objects[i].name),
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
    for (probe, b, outcome, a) in &results {
        let (what, rank, kind) = match *outcome {
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
        if rank < 3 && examples[rank].len() < EXAMPLES {
            examples[rank].push(Example {
                what: what.into(),
                kind,
                origin: probe.ray.origin.to_array(),
                direction: probe.ray.direction.to_array(),
                ours: describe(a, &probe.ray),
                referee: describe(b, &probe.ray),
                pixel: probe
                    .pixel
                    .map(|i| [i as u32 % options.width, i as u32 / options.width]),
            });
        }
    }
    let examples: Vec<Example> = examples.into_iter().flatten().take(EXAMPLES).collect();
    for (probe, b, outcome, _) in &results {
        let class = match *outcome {
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
                    let cos = b.map_or(0.0, |h| h.normal.dot(probe.ray.direction).abs());
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
        if let Some(i) = probe.pixel {
            pixels[i] = class;
        }
    }
    let mut shadow = ShadowStats::default();
    for (pixel, s) in &shadows {
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
            name: o.name.clone(),
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
    Ok(Report {
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
        kinds,
        shadow,
        failures,
        examples,
        pixels,
    })
}

/// A hit only our side has: counted under the object's kind, unless the referee skipped that
/// object (then there is nothing to compare with).
fn only_ours(kind: Kind, in_band: impl FnOnce() -> bool) -> Outcome {
    if kind == Kind::UncheckedSdf {
        Outcome::Unchecked
    } else {
        Outcome::Disagree {
            kind,
            in_band: in_band(),
        }
    }
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
    stats: &[KindStats; 4],
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
    let analytic = &stats[Kind::AnalyticSdf.index()];
    if analytic.rays > 0 && analytic.agreement_percent < 100.0 * SDF_AGREEMENT {
        out.push(format!(
            "analytic SDFs: hit/miss agreement {:.4}% < {:.1}% ({})",
            analytic.agreement_percent,
            100.0 * SDF_AGREEMENT,
            disagreements(analytic)
        ));
    }
    if analytic.disagree_elsewhere > 0 {
        out.push(format!(
            "analytic SDFs: {} hit/miss disagreements outside the ε band at silhouettes",
            analytic.disagree_elsewhere
        ));
    }
    if analytic.dt_over_tolerance > 0 {
        out.push(format!(
            "analytic SDFs: {} hits with |Δt| over max(10·ε(t), 2·ε(t)/|n·d|) (worst {:.2}× \
             the tolerance, max |Δt| {:.3e})",
            analytic.dt_over_tolerance, analytic.dt_worst_of_tolerance, analytic.dt_max
        ));
    }
    let meshed = &stats[Kind::MeshedSdf.index()];
    if meshed.disagree_elsewhere > 0 {
        out.push(format!(
            "meshed SDFs: {} hit/miss disagreements outside the mesher's tolerance band",
            meshed.disagree_elsewhere
        ));
    }
    if meshed.dt_over_tolerance > 0 {
        out.push(format!(
            "meshed SDFs: {} hits with |Δt| over (tolerance + 2·ε(t))/|n·d| (worst {:.2}× the \
             tolerance, max |Δt| {:.3e})",
            meshed.dt_over_tolerance, meshed.dt_worst_of_tolerance, meshed.dt_max
        ));
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
    let embree = super::embree::EmbreeScene::build_with(scene, reference)?;
    let checks = embree.checks.clone();
    let tracer = crate::trace::SceneTracer::new(scene);
    validate(scene, &tracer, &embree, &checks, options)
}

#[cfg(test)]
mod tests {
    use super::*;
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
        let p = probes(&scene, &opts).unwrap();
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
