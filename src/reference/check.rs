//! How the referee represents each SDF object: by a closed-form intersection, by the certified
//! root search of its tape, by a mesh of its field (with the mesh's stated tolerance), or not
//! at all, and why.

use serde::Serialize;
use std::fmt::Write;

/// How the referee represents one SDF object (the `checks` of the Embree scene,
/// and the report's).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "check", rename_all = "snake_case")]
pub enum SdfCheck {
    /// A closed-form ray intersection (Embree user geometry).
    Analytic,
    /// The field's first root along each ray, found by certified interval bisection of its
    /// tape in f64 (Embree user geometry): every crossing reported lies within `delta` of
    /// the true one, and a search that would need more than `max_boxes` interval evaluations
    /// is counted as uncertified, never answered by a guess.
    Certified {
        /// Width of the stretch a root is enclosed in (world units).
        delta: f64,
        /// Most interval evaluations per ray and object.
        max_boxes: u32,
        /// The field's Lipschitz bound the search prunes stretches with, where the lowering
        /// guarantees one.
        lipschitz: Option<f64>,
    },
    /// A triangle mesh extracted from the field by our mesher.
    Meshed {
        /// Grid cells along the longest side of the meshed box.
        resolution: u32,
        /// Edge length of one grid cell (world units).
        cell: f32,
        /// Largest distance (world units) of a mesh point from the true surface, as the mesher
        /// states it; a hit distance is compared within `tolerance / |n·d|`.
        tolerance: f32,
        /// Triangles of the mesh.
        triangles: usize,
        /// For an unbounded object meshed only inside a box (infinite repetition, say): that
        /// box as (min, max). A hit of the true surface outside it has no counterpart in the
        /// mesh, so rays whose hit lies there are left out of the comparison (and counted).
        clipped_to: Option<[[f32; 3]; 2]>,
    },
    /// Not represented: the object cannot be validated.
    Skipped {
        /// Why.
        why: String,
    },
}

impl SdfCheck {
    /// One line saying how the object is checked.
    pub fn describe(&self) -> String {
        match self {
            SdfCheck::Analytic => "analytic (closed-form intersection)".into(),
            SdfCheck::Certified {
                delta,
                max_boxes,
                lipschitz,
            } => format!(
                "certified: first root of the tape by f64 interval bisection{}, enclosed \
                 within δ = {delta:.1e} (at most {max_boxes} interval evaluations per ray)",
                match lipschitz {
                    Some(l) => format!(" and the field's Lipschitz bound {l}"),
                    None => String::new(),
                }
            ),
            SdfCheck::Meshed {
                resolution,
                cell,
                tolerance,
                triangles,
                clipped_to,
            } => {
                let mut s = format!(
                    "meshed: {resolution} cells along the longest side (cell {cell:.3e}), \
                     {triangles} triangles, tolerance {tolerance:.3e}"
                );
                if let Some([lo, hi]) = clipped_to {
                    let _ = write!(s, ", unbounded: meshed inside {lo:?}..{hi:?}");
                }
                s
            }
            SdfCheck::Skipped { why } => format!("SKIPPED: {why}"),
        }
    }
}
