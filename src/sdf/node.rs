//! The SDF tree as written in scene files: primitives, CSG, transforms, domain operators, implicits.
//!
//! Every node documents whether it yields an *exact* distance (a DIF: |f| is the Euclidean distance
//! to the surface) or a distance *bound* (a DUF: |f| ≤ distance, f = 0 exactly on the surface), and
//! its Lipschitz constant λ after the step correction that [`crate::sdf::lower`] applies. Hart
//! ("Sphere tracing", 1996, §2–3) shows that sphere tracing is safe (never steps through a surface)
//! whenever the traced function is 1-Lipschitz, so every node below is lowered to a field with
//! λ ≤ 1: nodes whose raw formula is steeper are divided by their λ.
//!
//! Formulas come from Inigo Quilez's catalogue ("distance functions", iquilezles.org, 2008–2024)
//! unless said otherwise.

use crate::geom::values::{Direction, Finite, FiniteVec3, NonNegative, Positive, PositiveVec3};
use serde::Deserialize;

/// One node of an SDF tree. Variant names and fields are the scene-file syntax.
// Fields are described in each variant's doc and, for users, in docs/scene-format.md.
#[allow(missing_docs)]
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum SdfNode {
    // ---- primitives (object space, centred at the origin) ----
    /// Sphere of the given radius. Exact; λ = 1.
    Sphere { radius: Positive },
    /// Axis-aligned box with the given half-extents. Exact; λ = 1 (Quilez `sdBox`).
    #[serde(rename = "Box")]
    Cuboid { half_extents: PositiveVec3 },
    /// Box with rounded edges: outer half-extents and the edge radius (≤ the smallest
    /// half-extent). Exact; λ = 1 (Quilez `sdRoundBox`).
    RoundBox {
        half_extents: PositiveVec3,
        radius: NonNegative,
    },
    /// Half-space below the plane n·p = offset (n is normalised on load). Exact; λ = 1.
    Plane { normal: Direction, offset: Finite },
    /// Torus in the xz-plane around the y axis. Exact; λ = 1 (Quilez `sdTorus`).
    Torus { major: Positive, minor: Positive },
    /// Cylinder along y with flat caps at ±half_height. Exact; λ = 1 (Quilez `sdCappedCylinder`).
    Cylinder {
        half_height: Positive,
        radius: Positive,
    },
    /// Cone frustum along y: `bottom_radius` at y = −half_height, `top_radius` at +half_height,
    /// flat caps; one radius may be 0. Exact; λ = 1 (Quilez `sdCappedCone`).
    Cone {
        half_height: Positive,
        bottom_radius: NonNegative,
        top_radius: NonNegative,
    },
    /// Capsule: all points within `radius` of the segment a–b. Exact; λ = 1 (Quilez `sdCapsule`).
    Capsule {
        a: FiniteVec3,
        b: FiniteVec3,
        radius: Positive,
    },
    /// Axis-aligned ellipsoid. Bound, not exact: max((|p/r| − 1)·min(r), |p| − max(r)), which
    /// is provably 1-Lipschitz (Quilez's popular k0(k0−1)/k1 estimate is not: the conformance
    /// suite measures λ ≈ 1.1 for it).
    Ellipsoid { radii: PositiveVec3 },
    /// Regular octahedron |x|+|y|+|z| = size. Exact; λ = 1 (Quilez `sdOctahedron`, exact form).
    Octahedron { size: Positive },
    /// Hexagonal prism along z: apothem `radius`, length 2·half_length. Exact; λ = 1
    /// (Quilez `sdHexPrism`).
    HexPrism {
        radius: Positive,
        half_length: Positive,
    },

    // ---- constructive solid geometry ----
    /// min of the children. Bound (exact outside the union); λ = 1.
    Union(Vec<SdfNode>),
    /// max of the children. Bound; λ = 1.
    Intersection(Vec<SdfNode>),
    /// max(base, −cut). Bound; λ = 1.
    Subtraction {
        base: Box<SdfNode>,
        cut: Box<SdfNode>,
    },
    /// Polynomial smooth minimum of the children, blend radius k (Quilez "smooth minimum", 2013):
    /// h = clamp(½ + ½(a−b)/k, 0, 1), f = a(1−h) + b·h − k·h(1−h). C1-continuous; its gradient is
    /// the convex combination (1−h)∇a + h∇b, so λ = 1. Materials blend with the same h.
    SmoothUnion {
        k: NonNegative,
        shapes: Vec<SdfNode>,
    },
    /// Smooth maximum, −smin(−a, −b, k). Bound; λ = 1.
    SmoothIntersection {
        k: NonNegative,
        shapes: Vec<SdfNode>,
    },
    /// Smooth max(base, −cut). Bound; λ = 1.
    SmoothSubtraction {
        k: NonNegative,
        base: Box<SdfNode>,
        cut: Box<SdfNode>,
    },
    /// Offset surface f − radius (inflates and rounds edges). Keeps exactness outside; λ = 1.
    Round {
        radius: NonNegative,
        shape: Box<SdfNode>,
    },
    /// Shell |f| − thickness. Exact where f is; λ = 1.
    Onion {
        thickness: Positive,
        shape: Box<SdfNode>,
    },

    // ---- transforms: applied as the inverse transform of the sample point ----
    /// Rotation (Euler angles in degrees, applied about x, then y, then z), uniform scale s and
    /// translation. The point is mapped by the inverse; the distance is multiplied by s, which
    /// keeps exact distances exact; λ = 1.
    Transform {
        #[serde(default)]
        translate: Option<FiniteVec3>,
        #[serde(default)]
        rotate: Option<FiniteVec3>,
        #[serde(default)]
        scale: Option<Positive>,
        shape: Box<SdfNode>,
    },
    /// Non-uniform scale: f(p/s)·min(s). Bound (the ratio of the largest to the smallest
    /// factor is the worst-case underestimate); λ = 1.
    Scale {
        factors: PositiveVec3,
        shape: Box<SdfNode>,
    },

    // ---- domain operators ----
    /// Infinite repetition with the given period on each axis (0 = not repeated on that axis):
    /// p ← p − c·⌊p/c + ½⌋. The child must fit inside its cell. The child is evaluated in its
    /// own cell and in the nearest neighbouring cell along each repeated axis, and the result is
    /// capped by a lower bound on the distance to every other copy (see `lower.rs`), so no copy
    /// is stepped through and empty cell walls never look like surfaces. Bound; λ = 1.
    Repeat {
        period: (NonNegative, NonNegative, NonNegative),
        shape: Box<SdfNode>,
    },
    /// Finite repetition: p ← p − c·clamp(⌊p/c + ½⌋, −n, n) gives 2n+1 copies per axis
    /// (Quilez "domain repetition", limited form); an axis with n = 0 is not repeated. Same
    /// neighbour evaluation and cap as `Repeat`. Bound; λ = 1.
    RepeatLimited {
        period: PositiveVec3,
        copies_each_side: (u32, u32, u32),
        shape: Box<SdfNode>,
    },
    /// Twist about the y axis by `rate` radians per unit of y. The map's Jacobian has largest
    /// singular value (k·r + √(4 + k²r²))/2 at distance r from the axis (derivation in
    /// `lower.rs`); with r the radius of the child's bounds, the field is divided by that λ and
    /// clipped to the bounding cylinder, so no holes appear.
    Twist { rate: Finite, shape: Box<SdfNode> },
    /// Bend in the xy-plane: the point is rotated about z by `rate`·x (Quilez `opCheapBend`).
    /// Its Jacobian norm is ≤ 1 + k·r with r = |p.xy|; the field is divided by that λ over the
    /// child's bounds and clipped to them.
    Bend { rate: Finite, shape: Box<SdfNode> },

    // ---- implicit surfaces ----
    /// An algebraic implicit surface f(x, y, z) = 0 written as an expression, e.g.
    /// `x*x + y*y + z*z - 1`. f is traced as f/λ (Hart 1996, §3.3) with λ its Lipschitz constant
    /// over the box |p| ≤ half_extents: given by the user or, when absent, estimated by sampling
    /// |∇f| on a grid over that box (times a 1.5 safety factor). The surface is clipped to the
    /// box: the field is max(f(π(p))/λ, box(p)) with π the projection onto the box, which is
    /// 1-Lipschitz everywhere when λ holds inside the box. f must be finite in the whole box.
    Implicit {
        expr: String,
        #[serde(default)]
        lipschitz: Option<Positive>,
        #[serde(default = "default_implicit_extent")]
        half_extents: PositiveVec3,
    },

    // ---- appearance ----
    /// Paints the subtree with a named material from the scene's `materials`.
    Material { name: String, shape: Box<SdfNode> },
}

fn default_implicit_extent() -> PositiveVec3 {
    PositiveVec3(glam::Vec3::splat(2.0))
}

impl SdfNode {
    /// Number of nodes in this subtree (for `info` and limits).
    pub fn node_count(&self) -> usize {
        1 + self
            .children()
            .iter()
            .map(|c| c.node_count())
            .sum::<usize>()
    }

    /// Whether the field this node lowers to is a convex function of the point. The signed
    /// distance to a closed convex set is one (it is the supremum over unit vectors a of the
    /// affine functions a·p − h(a), h the set's support function: Boyd & Vandenberghe, *Convex
    /// Optimization*, §3.2.3), so every primitive is but the torus: the exact ones are signed
    /// distances to convex sets, the ellipsoid's bound is the maximum of two norms less
    /// constants. Convexity survives a maximum (intersection), the smooth maximum (Quilez's
    /// polynomial one is convex and nondecreasing in both arguments), subtracting a constant
    /// (rounding), an affine map of the point times a positive factor (transforms, non-uniform
    /// scale) and painting. Unions, subtractions, shells, domain operators and implicits are
    /// taken as not convex. The tracer's penumbra march bounds a convex field beyond its
    /// samples by the extension of their chord.
    pub fn is_convex(&self) -> bool {
        use SdfNode::*;
        match self {
            Sphere { .. }
            | Cuboid { .. }
            | RoundBox { .. }
            | Plane { .. }
            | Cylinder { .. }
            | Cone { .. }
            | Capsule { .. }
            | Ellipsoid { .. }
            | Octahedron { .. }
            | HexPrism { .. } => true,
            Intersection(v) | SmoothIntersection { shapes: v, .. } => {
                !v.is_empty() && v.iter().all(SdfNode::is_convex)
            }
            Round { shape, .. }
            | Transform { shape, .. }
            | Scale { shape, .. }
            | Material { shape, .. } => shape.is_convex(),
            Torus { .. }
            | Union(_)
            | Subtraction { .. }
            | SmoothUnion { .. }
            | SmoothSubtraction { .. }
            | Onion { .. }
            | Repeat { .. }
            | RepeatLimited { .. }
            | Twist { .. }
            | Bend { .. }
            | Implicit { .. } => false,
        }
    }

    /// The Lipschitz bound the lowering guarantees for this node's field: 1, as every node is
    /// lowered to λ ≤ 1 (see the module docs), except where an implicit surface's λ is only
    /// an estimate (or the user's word): `None` there.
    pub fn guaranteed_lipschitz(&self) -> Option<f32> {
        fn has_implicit(node: &SdfNode) -> bool {
            matches!(node, SdfNode::Implicit { .. })
                || node.children().into_iter().any(has_implicit)
        }
        (!has_implicit(self)).then_some(1.0)
    }

    /// The direct children of this node.
    pub fn children(&self) -> Vec<&SdfNode> {
        use SdfNode::*;
        match self {
            Union(v) | Intersection(v) => v.iter().collect(),
            SmoothUnion { shapes, .. } | SmoothIntersection { shapes, .. } => {
                shapes.iter().collect()
            }
            Subtraction { base, cut } | SmoothSubtraction { base, cut, .. } => {
                vec![base.as_ref(), cut.as_ref()]
            }
            Round { shape, .. }
            | Onion { shape, .. }
            | Transform { shape, .. }
            | Scale { shape, .. }
            | Repeat { shape, .. }
            | RepeatLimited { shape, .. }
            | Twist { shape, .. }
            | Bend { shape, .. }
            | Material { shape, .. } => vec![shape.as_ref()],
            _ => Vec::new(),
        }
    }

    /// The variant name as written in scene files.
    pub fn kind(&self) -> &'static str {
        use SdfNode::*;
        match self {
            Sphere { .. } => "Sphere",
            Cuboid { .. } => "Box",
            RoundBox { .. } => "RoundBox",
            Plane { .. } => "Plane",
            Torus { .. } => "Torus",
            Cylinder { .. } => "Cylinder",
            Cone { .. } => "Cone",
            Capsule { .. } => "Capsule",
            Ellipsoid { .. } => "Ellipsoid",
            Octahedron { .. } => "Octahedron",
            HexPrism { .. } => "HexPrism",
            Union(_) => "Union",
            Intersection(_) => "Intersection",
            Subtraction { .. } => "Subtraction",
            SmoothUnion { .. } => "SmoothUnion",
            SmoothIntersection { .. } => "SmoothIntersection",
            SmoothSubtraction { .. } => "SmoothSubtraction",
            Round { .. } => "Round",
            Onion { .. } => "Onion",
            Transform { .. } => "Transform",
            Scale { .. } => "Scale",
            Repeat { .. } => "Repeat",
            RepeatLimited { .. } => "RepeatLimited",
            Twist { .. } => "Twist",
            Bend { .. } => "Bend",
            Implicit { .. } => "Implicit",
            Material { .. } => "Material",
        }
    }
}
