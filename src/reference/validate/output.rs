//! The validation's output: the mismatch image and its legend, the report as Markdown and as a
//! page to browse.

use super::aggregate::{KindRow, PixelClass, Report};
use super::classify::Kind;
use std::fmt::Write as _;

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

impl Report {
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
        let shadow: Vec<Row> = [
            ("cast", sh.rays.to_string()),
            ("agree", format!("{:.3}%", sh.agreement_percent)),
            (
                "disagree at grazing angles",
                sh.disagree_grazing.to_string(),
            ),
            ("disagree elsewhere", sh.disagree_elsewhere.to_string()),
            (
                "left out: our occluder beyond a clipped object's mesh",
                sh.excluded_outside_mesh.to_string(),
            ),
            (
                "left out: meshed blocker within the mesh's tolerance",
                sh.within_mesh_tolerance.to_string(),
            ),
        ]
        .into_iter()
        .map(|(label, value)| cells(vec![label.into(), value]))
        .collect();
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
        if self.uncertified_searches > 0 {
            let _ = writeln!(
                s,
                "| (uncertified root searches: out of interval evaluations) | {} | | | | | | | | | |",
                self.uncertified_searches
            );
        }
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
