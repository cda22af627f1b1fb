//! Bad input never panics or hangs: it gives an error that names the file and the place.
//!
//! Library level: every malformed or invalid scene goes through both [`Scene::from_source`]
//! (with the name `bad.ron`) and [`Scene::load`] (on a file in a fresh temporary directory), and
//! the message must start with `file:line:column:`, where the line is exactly the line of the
//! offending token and the column lies within that token or right next to it. Tests mark the
//! offending token in their input as `«token»`; the markers are removed before loading and give
//! the expected line and column.
//!
//! Binary level: the `hytrace` executable fails with a non-zero exit status and a plain message
//! (never a panic) on bad arguments, and renders a tiny valid image.
//!
//! Last, a small deterministic fuzz test mutates the showcase scene a few hundred times and
//! checks that loading never panics.

mod common;

use hytrace::scene::Scene;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The showcase scene, a valid starting point for mutations.
const SHOWCASE: &str = include_str!("../assets/scenes/showcase.ron");

/// How far (in characters) a reported column may lie outside the marked token.
const COLUMN_SLACK: usize = 2;

// ---------------------------------------------------------------------------------------------
// helpers
// ---------------------------------------------------------------------------------------------

/// A fresh temporary folder (removed on drop) with helpers for the files of a test.
struct TempDir(tempfile::TempDir);

impl TempDir {
    fn new(tag: &str) -> TempDir {
        TempDir(common::temp_dir(&format!("bad-input-{tag}")))
    }

    fn path(&self, name: &str) -> PathBuf {
        self.0.path().join(name)
    }

    fn write(&self, name: &str, contents: impl AsRef<[u8]>) -> PathBuf {
        let p = self.path(name);
        std::fs::write(&p, contents).expect("write temp file");
        p
    }
}

/// A scene source with the offending token marked, split into the clean source and the
/// expected place.
struct Marked {
    source: String,
    line: usize,
    /// Column (1-based, in characters) of the first character of the token.
    first_col: usize,
    /// Column of the last character of the token.
    last_col: usize,
    token: String,
}

fn unmark(marked: &str) -> Marked {
    let open = marked.find('«').expect("test input needs a « marker");
    let close = marked.find('»').expect("test input needs a » marker");
    assert!(open < close, "« must come before »");
    let token = &marked[open + '«'.len_utf8()..close];
    assert!(
        !token.is_empty() && !token.contains('\n'),
        "the marked token must be one non-empty line"
    );
    let before = &marked[..open];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let first_col = before[line_start..].chars().count() + 1;
    Marked {
        source: format!("{before}{token}{}", &marked[close + '»'.len_utf8()..]),
        line,
        first_col,
        last_col: first_col + token.chars().count() - 1,
        token: token.to_string(),
    }
}

/// `camera` plus `body`, inside `Scene( ... )`. `body` holds the fields after the camera, each
/// line indented and ending with a comma.
fn scene(body: &str) -> String {
    format!("Scene(\n    camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)),\n{body})\n")
}

/// Parses the `line:column` after `file:` at the start of `message`.
fn place_in(message: &str, file: &str) -> Option<(usize, usize)> {
    let rest = message.strip_prefix(file)?.strip_prefix(':')?;
    let mut parts = rest.splitn(3, ':');
    let line = parts.next()?.parse().ok()?;
    let column = parts.next()?.parse().ok()?;
    parts.next()?;
    Some((line, column))
}

/// The source with line numbers around `line`, for failure messages.
fn excerpt(source: &str, line: usize) -> String {
    source
        .lines()
        .enumerate()
        .filter(|(i, _)| i + 3 >= line && *i <= line + 1)
        .map(|(i, l)| format!("{:>4} | {}\n", i + 1, clip(l)))
        .collect()
}

/// At most 200 characters of `s`, for failure messages.
fn clip(s: &str) -> String {
    if s.chars().count() <= 200 {
        s.to_string()
    } else {
        format!("{}…", s.chars().take(200).collect::<String>())
    }
}

/// Checks one error message against the expected file, place and key words.
fn check_message(message: &str, file: &str, m: &Marked, keywords: &[&str], how: &str) {
    let context = || {
        format!(
            "[{how}] message: {}\nexpected {file}:{}:{}..={} (token `{}`)\n{}",
            clip(message),
            m.line,
            m.first_col,
            m.last_col,
            clip(&m.token),
            excerpt(&m.source, m.line)
        )
    };
    assert!(!message.contains("panicked"), "{}", context());
    let (line, column) = place_in(message, file).unwrap_or_else(|| {
        panic!(
            "message does not start with `{file}:line:column:`\n{}",
            context()
        )
    });
    assert_eq!(line, m.line, "wrong line\n{}", context());
    assert!(
        column + COLUMN_SLACK >= m.first_col && column <= m.last_col + COLUMN_SLACK,
        "column {column} is not at the offending token\n{}",
        context()
    );
    let lower = message.to_lowercase();
    for k in keywords {
        assert!(
            lower.contains(&k.to_lowercase()),
            "message lacks the key word `{k}`\n{}",
            context()
        );
    }
}

/// Loads `marked` (see [`unmark`]) with `from_source` and with `load` from a file; both must
/// fail with the marked place and every key word. Returns the `from_source` message.
fn expect_error(marked: &str, keywords: &[&str]) -> String {
    let m = unmark(marked);
    let message = match std::panic::catch_unwind(|| {
        Scene::from_source(&m.source, Path::new("bad.ron")).map(|_| ())
    }) {
        Ok(Ok(())) => panic!(
            "loaded without error, expected one at line {} (`{}`):\n{}",
            m.line, m.token, m.source
        ),
        Ok(Err(e)) => e.to_string(),
        Err(_) => panic!("Scene::from_source panicked on:\n{}", m.source),
    };
    check_message(&message, "bad.ron", &m, keywords, "from_source");

    let dir = TempDir::new("load");
    let path = dir.write("scene under test.ron", &m.source);
    let file = path.display().to_string();
    let message_from_file = match Scene::load(&path) {
        Ok(_) => panic!(
            "Scene::load accepted what from_source refused:\n{}",
            m.source
        ),
        Err(e) => e.to_string(),
    };
    check_message(&message_from_file, &file, &m, keywords, "load");
    message
}

/// Loads `source`, which must succeed (a valid control case).
fn expect_ok(source: &str) -> Scene {
    match Scene::from_source(source, Path::new("good.ron")) {
        Ok(s) => s,
        Err(e) => panic!("valid scene refused: {e}\n{source}"),
    }
}

// ---------------------------------------------------------------------------------------------
// library level: syntax
// ---------------------------------------------------------------------------------------------

#[test]
fn control_scene_loads() {
    let s = expect_ok(&scene(
        "    objects: [\n        (shape: Sphere(radius: 1)),\n    ],\n",
    ));
    assert_eq!(s.objects.len(), 1);
    expect_ok(SHOWCASE);
}

#[test]
fn syntax_missing_closing_paren() {
    // The object's `(` is never closed: the parser trips over the `]`.
    expect_error(
        &scene(
            "    objects: [\n        (shape: Sphere(radius: 1)«]»,\n    image: (width: 4, height: 4),\n",
        ),
        &["expected"],
    );
}

#[test]
fn syntax_missing_closing_paren_message_is_not_empty() {
    let msg = expect_error(
        &scene("    objects: [\n        (shape: Sphere(radius: 1)«]»,\n"),
        &["expected"],
    );
    let text = msg.splitn(4, ':').nth(3).unwrap_or("").trim();
    assert!(!text.is_empty(), "empty message: {msg}");
}

#[test]
fn syntax_missing_comma_between_fields() {
    expect_error(
        "Scene(\n    image: (width: 4, height: 4)\n    «camera»: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)),\n)\n",
        &["comma"],
    );
}

#[test]
fn syntax_missing_comma_between_objects() {
    expect_error(
        &scene(
            "    objects: [\n        (shape: Sphere(radius: 1))\n        «(»shape: Sphere(radius: 2)),\n    ],\n",
        ),
        &["comma"],
    );
}

// ---------------------------------------------------------------------------------------------
// library level: unknown names
// ---------------------------------------------------------------------------------------------

#[test]
fn unknown_field_in_image() {
    expect_error(
        &scene("    image: (\n        width: 8,\n        «hieght»: 8,\n    ),\n"),
        &["hieght", "height"],
    );
}

#[test]
fn unknown_field_in_material() {
    expect_error(
        &scene(
            "    materials: {\n        \"red\": (color: (1, 0, 0)),\n        \"steel\": (color: (0.5, 0.5, 0.5), «roughness»: 0.3),\n    },\n",
        ),
        &["roughness"],
    );
}

#[test]
fn metallic_roughness_material_errors_name_the_field_and_the_range() {
    expect_error(
        &scene(
            "    materials: {\n        \"red\": (color: (1, 0, 0)),\n        \"gold\": Pbr(base_color: (1, 0.8, 0.3), «metalic»: 1),\n    },\n",
        ),
        &["metalic", "metallic"],
    );
    expect_error(
        &scene("    materials: {\n        \"m\": Pbr(metallic: «2»),\n    },\n"),
        &["[0, 1]", "2"],
    );
    expect_error(
        &scene(
            "    materials: {\n        \"m\": Pbr(\n            roughness: «NaN»,\n        ),\n    },\n",
        ),
        &["finite"],
    );
    expect_error(
        &scene("    materials: {\n        \"m\": Pbr(emissive: «(1, -1, 0)»),\n    },\n"),
        &[">= 0"],
    );
}

#[test]
fn spot_light_cone_and_range_errors() {
    expect_error(
        &scene(
            "    lights: [\n        «Spot»(position: (0, 1, 0), direction: (0, -1, 0), intensity: 1, inner_angle: 40, outer_angle: 30),\n    ],\n",
        ),
        &["inner_angle", "outer_angle", "40", "30"],
    );
    expect_error(
        &scene(
            "    lights: [\n        «Spot»(position: (0, 1, 0), direction: (0, -1, 0), intensity: 1, outer_angle: 120),\n    ],\n",
        ),
        &["outer_angle", "120", "90"],
    );
    expect_error(
        &scene(
            "    lights: [\n        Point(position: (0, 1, 0), intensity: 1, range: «0»),\n    ],\n",
        ),
        &["> 0"],
    );
    expect_error(
        &scene(
            "    lights: [\n        Spot(position: (0, 1, 0), direction: «(0, 0, 0)», intensity: 1),\n    ],\n",
        ),
        &["non-zero direction"],
    );
}

#[test]
fn unknown_field_in_sdf_node() {
    expect_error(
        &scene("    objects: [\n        (shape: Sphere(«radus»: 1)),\n    ],\n"),
        &["radus", "radius"],
    );
}

#[test]
fn unknown_field_in_object() {
    expect_error(
        &scene(
            "    objects: [\n        (\n            shape: Sphere(radius: 1),\n            «colour»: \"red\",\n        ),\n    ],\n",
        ),
        &["colour"],
    );
}

#[test]
fn unknown_sdf_node_kind() {
    expect_error(
        &scene(
            "    objects: [\n        (shape: Union([\n            Sphere(radius: 1),\n            «Spheer»(radius: 2),\n        ])),\n    ],\n",
        ),
        &["Spheer"],
    );
}

#[test]
fn unknown_top_level_field() {
    expect_error(&scene("    «meshes»: [],\n"), &["meshes"]);
}

// ---------------------------------------------------------------------------------------------
// library level: bad numbers
// ---------------------------------------------------------------------------------------------

#[test]
fn negative_radius() {
    expect_error(
        &scene("    objects: [\n        (shape: Sphere(radius: «-1»)),\n    ],\n"),
        &["> 0", "-1"],
    );
}

#[test]
fn zero_radius() {
    expect_error(
        &scene("    objects: [\n        (shape: Sphere(radius: «0»)),\n    ],\n"),
        &["> 0"],
    );
    expect_error(
        &scene(
            "    objects: [\n        (shape: Cylinder(half_height: 1, radius: «0.0»)),\n    ],\n",
        ),
        &["> 0"],
    );
}

#[test]
fn non_finite_radius() {
    for bad in ["NaN", "inf", "-inf", "1e39"] {
        expect_error(
            &scene(&format!(
                "    objects: [\n        (shape: Sphere(radius: «{bad}»)),\n    ],\n"
            )),
            &["finite"],
        );
    }
}

#[test]
fn non_finite_translate() {
    for bad in ["NaN", "inf", "-inf", "1e39"] {
        expect_error(
            &scene(&format!(
                "    objects: [\n        (\n            shape: Sphere(radius: 1),\n            translate: «(0, {bad}, 0)»,\n        ),\n    ],\n"
            )),
            &["finite"],
        );
    }
}

#[test]
fn non_finite_colour() {
    for bad in ["NaN", "inf", "1e39"] {
        expect_error(
            &scene(&format!(
                "    materials: {{\n        \"m\": (\n            color: «({bad}, 0.5, 0.5)»,\n        ),\n    }},\n"
            )),
            &["finite"],
        );
        expect_error(
            &scene(&format!(
                "    lights: [\n        Ambient(color: «(0.5, 0.5, {bad})», intensity: 1),\n    ],\n"
            )),
            &["finite"],
        );
    }
}

#[test]
fn negative_colour() {
    expect_error(
        &scene("    materials: {\n        \"m\": (color: «(0.5, -0.1, 0.5)»),\n    },\n"),
        &[">= 0"],
    );
    expect_error(
        &scene("    image: (width: 4, height: 4, background: «(-1, 0, 0)»),\n"),
        &[">= 0"],
    );
}

#[test]
fn reflectivity_above_one() {
    expect_error(
        &scene(
            "    materials: {\n        \"mirror\": (\n            color: (1, 1, 1),\n            reflectivity: «1.5»,\n        ),\n    },\n",
        ),
        &["[0, 1]", "1.5"],
    );
}

#[test]
fn negative_light_intensity() {
    expect_error(
        &scene("    lights: [\n        Point(position: (0, 5, 0), intensity: «-3»),\n    ],\n"),
        &[">= 0"],
    );
}

#[test]
fn zero_direction() {
    expect_error(
        &scene(
            "    lights: [\n        Directional(«direction: (0, 0, 0)», intensity: 1),\n    ],\n",
        ),
        &["direction"],
    );
}

// ---------------------------------------------------------------------------------------------
// library level: settings
// ---------------------------------------------------------------------------------------------

#[test]
fn zero_width_image_one_line() {
    expect_error(
        &scene("    «image: (width: 0, height: 8)»,\n"),
        &["width", "empty"],
    );
}

/// The image block over several lines: the error must point at the `width: 0` line, not at
/// `image:` two lines above it.
#[test]
fn zero_width_image_multiline() {
    expect_error(
        &scene("    image: (\n        height: 8,\n        «width: 0»,\n    ),\n"),
        &["width", "empty"],
    );
}

/// A scene's exposure is checked where it is read: the file and its place, not a flag the
/// user never gave.
#[test]
fn exposure_out_of_range() {
    let message = expect_error(
        &scene("    image: (\n        width: 8,\n        «exposure: 65»,\n    ),\n"),
        &["exposure", "65", "out of range"],
    );
    assert!(!message.contains("--exposure"), "{message}");
}

#[test]
fn huge_image_one_line() {
    expect_error(
        &scene("    «image: (width: 100000, height: 8)»,\n"),
        &["too large", "100000"],
    );
}

#[test]
fn huge_image_multiline() {
    expect_error(
        &scene("    image: (\n        height: 8,\n        «width: 100000»,\n    ),\n"),
        &["too large", "100000"],
    );
}

#[test]
fn zero_samples() {
    expect_error(
        &scene("    image: (width: 8, height: 8, «samples: 0»),\n"),
        &["samples", "range"],
    );
}

/// A comment that mentions `samples` before the real field must not capture the error.
#[test]
fn zero_samples_after_a_comment_mentioning_samples() {
    expect_error(
        "// A tiny scene: 8x8 pixels, a few samples per pixel.\nScene(\n    camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)),\n    image: (width: 8, height: 8, «samples: 0»),\n)\n",
        &["samples", "range"],
    );
}

#[test]
fn zero_max_steps() {
    expect_error(
        &scene("    tracer: (epsilon: 1e-4, «max_steps: 0»),\n"),
        &["max_steps", "range"],
    );
}

#[test]
fn camera_position_equals_look_at() {
    expect_error(
        "Scene(\n    image: (width: 8, height: 8),\n    «camera: Perspective(position: (1, 2, 3), look_at: (1, 2, 3))»,\n)\n",
        &["same point"],
    );
    expect_error(
        "Scene(\n    «camera: Orthographic(position: (0, 0, 0), look_at: (0, 0, 0), height: 2)»,\n)\n",
        &["same point"],
    );
}

#[test]
fn camera_up_parallel_to_view() {
    expect_error(
        "Scene(\n    «camera: Perspective(position: (0, 5, 0), look_at: (0, 0, 0), up: (0, 1, 0))»,\n)\n",
        &["parallel"],
    );
}

#[test]
fn camera_fov_too_wide() {
    expect_error(
        "Scene(\n    camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), «fov: 200»),\n)\n",
        &["fov", "179"],
    );
}

#[test]
fn missing_camera() {
    // No camera at all: the error is at the end of the struct.
    let msg = expect_error(
        "Scene(\n    image: (width: 8, height: 8),\n«)»\n",
        &["camera"],
    );
    assert!(msg.contains("camera"), "{msg}");
}

// ---------------------------------------------------------------------------------------------
// library level: materials
// ---------------------------------------------------------------------------------------------

const TWO_MATERIALS: &str = "    materials: {\n        \"red\": (color: (1, 0, 0)),\n        \"blue\": (color: (0, 0, 1)),\n    },\n";

#[test]
fn unknown_material_on_object() {
    expect_error(
        &scene(&format!(
            "{TWO_MATERIALS}    objects: [\n        (shape: Sphere(radius: 1), material: \"red\"),\n        (\n            name: \"ball\",\n            shape: Sphere(radius: 1),\n            material: «\"chrome\"»,\n        ),\n    ],\n"
        )),
        &["unknown material", "chrome", "red", "blue", "ball"],
    );
}

#[test]
fn unknown_material_in_material_node() {
    expect_error(
        &scene(&format!(
            "{TWO_MATERIALS}    objects: [\n        (\n            shape: Union([\n                Material(name: \"red\", shape: Sphere(radius: 1)),\n                Material(name: «\"chrome\"», shape: Box(half_extents: (1, 1, 1))),\n            ]),\n        ),\n    ],\n"
        )),
        &["unknown material", "chrome", "red", "blue"],
    );
}

/// An object named after its (missing) material: the line must be the `material:` line, not
/// the `name:` line above it.
#[test]
fn unknown_material_on_object_named_like_it() {
    expect_error(
        &scene(&format!(
            "{TWO_MATERIALS}    objects: [\n        (\n            name: \"gold\",\n            shape: Sphere(radius: 1),\n            material: «\"gold\"»,\n        ),\n    ],\n"
        )),
        &["unknown material", "gold", "red", "blue"],
    );
}

#[test]
fn unknown_material_with_no_materials_defined() {
    expect_error(
        &scene(
            "    objects: [\n        (shape: Sphere(radius: 1), material: «\"red\"»),\n    ],\n",
        ),
        &["unknown material", "red", "none"],
    );
}

// ---------------------------------------------------------------------------------------------
// library level: shapes that cannot be lowered
// ---------------------------------------------------------------------------------------------

#[test]
fn torus_minor_exceeds_major() {
    expect_error(
        &scene(
            "    objects: [\n        (shape: Sphere(radius: 1)),\n        (\n            translate: (3, 0, 0),\n            shape: «Torus(major: 0.5, minor: 1)»,\n        ),\n    ],\n",
        ),
        &["minor", "major", "Torus"],
    );
}

/// Two tori in one object, the second one bad: the line must be the second torus's.
#[test]
fn torus_error_points_at_the_bad_torus_not_the_first() {
    expect_error(
        &scene(
            "    objects: [\n        (\n            shape: Union([\n                Torus(major: 1, minor: 0.25),\n                «Torus(major: 0.5, minor: 1)»,\n            ]),\n        ),\n    ],\n",
        ),
        &["minor", "major"],
    );
}

/// A comment inside the object that mentions the node kind must not capture the error.
#[test]
fn lowering_error_not_captured_by_a_comment() {
    expect_error(
        &scene(
            "    objects: [\n        (\n            // a RoundBox with soft edges\n            shape: «RoundBox(half_extents: (1, 0.5, 1), radius: 0.6)»,\n        ),\n    ],\n",
        ),
        &["radius", "half-extent"],
    );
}

#[test]
fn roundbox_radius_exceeds_half_extent() {
    expect_error(
        &scene(
            "    objects: [\n        (shape: «RoundBox(half_extents: (1, 0.5, 1), radius: 0.6)»),\n    ],\n",
        ),
        &["radius", "half-extent", "RoundBox"],
    );
}

#[test]
fn repeat_child_does_not_fit_its_cell() {
    expect_error(
        &scene(
            "    objects: [\n        (\n            name: \"row\",\n            shape: «Repeat(period: (1, 0, 0), shape: Sphere(radius: 1))»,\n        ),\n    ],\n",
        ),
        &["fit", "period", "row"],
    );
    expect_error(
        &scene(
            "    objects: [\n        (shape: «RepeatLimited(period: (1, 1, 1), copies_each_side: (2, 2, 2), shape: Box(half_extents: (0.6, 0.1, 0.1)))»),\n    ],\n",
        ),
        &["fit", "period"],
    );
}

#[test]
fn repeat_with_zero_period_everywhere() {
    expect_error(
        &scene(
            "    objects: [\n        (shape: «Repeat(period: (0, 0, 0), shape: Sphere(radius: 1))»),\n    ],\n",
        ),
        &["period"],
    );
}

#[test]
fn twist_of_unbounded_child() {
    expect_error(
        &scene(
            "    objects: [\n        (shape: «Twist(rate: 1, shape: Plane(normal: (0, 1, 0), offset: 0))»),\n    ],\n",
        ),
        &["unbounded", "Plane", "Twist"],
    );
    expect_error(
        &scene(
            "    objects: [\n        (shape: «Bend(rate: 1, shape: Repeat(period: (2, 0, 0), shape: Sphere(radius: 0.5)))»),\n    ],\n",
        ),
        &["unbounded", "Bend"],
    );
}

#[test]
fn implicit_syntax_error() {
    // `*` at column 7 of the expression.
    expect_error(
        &scene("    objects: [\n        (shape: «Implicit(expr: \"x*x + * y - 1\")»),\n    ],\n"),
        &["expression", "column 7", "x*x + * y - 1"],
    );
    // unclosed parenthesis
    expect_error(
        &scene(
            "    objects: [\n        (shape: «Implicit(expr: \"sqrt(x*x + y*y - 1\")»),\n    ],\n",
        ),
        &["expression", "column"],
    );
}

#[test]
fn implicit_unknown_identifier() {
    expect_error(
        &scene("    objects: [\n        (shape: «Implicit(expr: \"x*x + w*w - 1\")»),\n    ],\n"),
        &["expression", "column 7", "unknown identifier", "`w`"],
    );
}

/// `Implicit(` on one line, `expr:` on the next (the showcase's own layout): the line must be
/// the expression's.
#[test]
fn implicit_error_line_is_the_expression_line() {
    expect_error(
        &scene(
            "    objects: [\n        (\n            shape: Implicit(\n                expr: «\"x*x + w*w - 1\"»,\n                half_extents: (1.3, 1.3, 1.3),\n            ),\n        ),\n    ],\n",
        ),
        &["expression", "column 7", "`w`"],
    );
}

/// A hexadecimal (or binary, octal) number is named as such, with its decimal value, wherever
/// the parser stops on it: a positive radius read as 0, a vector's component.
#[test]
fn non_decimal_numbers_are_named() {
    expect_error(
        &scene("    objects: [\n        (shape: Sphere(radius: «0x10»)),\n    ],\n"),
        &["`0x10`", "decimal", "16"],
    );
    expect_error(
        &scene("    objects: [\n        (shape: Box(half_extents: (1, «0b11», 1))),\n    ],\n"),
        &["`0b11`", "decimal", "3"],
    );
    // where the parser stops after the 0, at the x
    let message = expect_error(
        &scene(
            "    objects: [\n        (shape: Transform(translate: («0x2», 0, 0), shape: Sphere(radius: 1))),\n    ],\n",
        ),
        &["`0x2`", "decimal", "2"],
    );
    assert!(!message.contains("Expected comma"), "{message}");
}

/// A box past the coordinates the trees take is named as such, not as a NaN the sampling of
/// the box made.
#[test]
fn implicit_box_beyond_the_trees_reach() {
    let message = expect_error(
        &scene(
            "    objects: [\n        (\n            shape: Implicit(\n                expr: \"x*x + y*y + z*z - 1\",\n                «half_extents: (3e38, 3e38, 3e38)»,\n            ),\n        ),\n    ],\n",
        ),
        &["half_extents", "3e38", "1e18"],
    );
    assert!(!message.contains("NaN"), "{message}");
}

#[test]
fn implicit_empty_and_huge_expressions() {
    expect_error(
        &scene("    objects: [\n        (shape: «Implicit(expr: \"\")»),\n    ],\n"),
        &["expression"],
    );
    // 100 000 nested parentheses: the expression parser's nesting limit, not a stack overflow.
    let deep = format!("{}x{}", "(".repeat(100_000), ")".repeat(100_000));
    expect_error(
        &scene(&format!(
            "    objects: [\n        (shape: «Implicit(expr: \"{deep}\")»),\n    ],\n"
        )),
        &["expression"],
    );
    // a 100 000-term sum: the tree depth limit
    let long = vec!["x"; 100_000].join("+");
    let message = expect_error(
        &scene(&format!(
            "    objects: [\n        (shape: «Implicit(expr: \"{long}\")»),\n    ],\n"
        )),
        &["expression"],
    );
    // The error quotes the expression's start, not 200 KB of it.
    assert!(
        message.len() < 1000 && message.contains("x+x+x") && message.contains('…'),
        "{}",
        &message[..message.len().min(300)]
    );
}

#[test]
fn empty_union() {
    expect_error(
        &scene("    objects: [\n        (shape: «Union([])»),\n    ],\n"),
        &["Union", "at least one"],
    );
    expect_error(
        &scene(
            "    objects: [\n        (shape: Union([\n            Sphere(radius: 1),\n            «SmoothUnion(k: 0.2, shapes: [])»,\n        ])),\n    ],\n",
        ),
        &["SmoothUnion", "at least one"],
    );
}

#[test]
fn implicit_constant_expression() {
    // No gradient anywhere: no Lipschitz constant can be estimated.
    expect_error(
        &scene("    objects: [\n        (shape: «Implicit(expr: \"1\")»),\n    ],\n"),
        &["lipschitz"],
    );
}

/// Not bad input, found while probing limits: a plain union of 17 spheres (all with the
/// default material) is refused with "too complex: needs more than 16 material registers",
/// because every child is lowered before the union folds them, so all their material loads are
/// live at once. It must load (or, if a limit is hit, fail with a clear message at the Union).
#[test]
fn union_of_seventeen_spheres_loads() {
    let kids: Vec<String> = (0..17)
        .map(|i| {
            format!("            Transform(translate: ({i}, 0, 0), shape: Sphere(radius: 0.4)),\n")
        })
        .collect();
    expect_ok(&scene(&format!(
        "    objects: [\n        (shape: Union([\n{}        ])),\n    ],\n",
        kids.concat()
    )));
}

/// A union too large for the tape must fail with a place and a clear reason, not a panic.
#[test]
fn huge_union_fails_clearly() {
    let kids: Vec<String> = (0..5000)
        .map(|i| format!("Sphere(radius: 0.{})", i % 9 + 1))
        .collect();
    let src = scene(&format!(
        "    objects: [\n        (shape: Union([{}])),\n    ],\n",
        kids.join(", ")
    ));
    match Scene::from_source(&src, Path::new("big.ron")) {
        Ok(_) => {}
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.starts_with("big.ron:4:"), "{msg}");
            assert!(msg.contains("too complex"), "{msg}");
        }
    }
}

#[test]
fn cone_with_both_radii_zero() {
    expect_error(
        &scene(
            "    objects: [\n        (shape: «Cone(half_height: 1, bottom_radius: 0, top_radius: 0)»),\n    ],\n",
        ),
        &["radius"],
    );
}

// ---------------------------------------------------------------------------------------------
// library level: files
// ---------------------------------------------------------------------------------------------

/// A variable no environment sets: named for these tests alone (they only read it).
const UNSET_VARIABLE: &str = "HYTRACE_TEST_VARIABLE_NEVER_SET";

#[test]
fn mesh_path_with_an_unset_variable() {
    expect_error(
        &scene(&format!(
            "    objects: [\n        (name: \"model\", mesh: «\"${UNSET_VARIABLE}/model.obj\"»),\n    ],\n"
        )),
        &["model", UNSET_VARIABLE, "not set"],
    );
}

#[test]
fn missing_file() {
    let dir = TempDir::new("missing");
    let path = dir.path("no such scene.ron");
    let msg = Scene::load(&path)
        .expect_err("a missing file loads")
        .to_string();
    assert!(msg.starts_with(&path.display().to_string()), "{msg}");
    assert!(msg.contains("cannot read"), "{msg}");
}

#[test]
fn directory_instead_of_file() {
    let dir = TempDir::new("dir");
    let sub = dir.path("scene.ron");
    std::fs::create_dir(&sub).unwrap();
    let msg = Scene::load(&sub)
        .expect_err("a directory loads")
        .to_string();
    assert!(msg.starts_with(&sub.display().to_string()), "{msg}");
    assert!(msg.contains("cannot read"), "{msg}");
}

#[test]
fn empty_file() {
    let dir = TempDir::new("empty");
    for (name, contents) in [
        ("empty.ron", ""),
        ("blank.ron", "\n\n   \n"),
        ("comment.ron", "// nothing here\n"),
    ] {
        let path = dir.write(name, contents);
        let msg = Scene::load(&path)
            .expect_err("an empty file loads")
            .to_string();
        let file = path.display().to_string();
        let (line, _) = place_in(&msg, &file).unwrap_or_else(|| panic!("no place: {msg}"));
        assert!(
            line >= 1 && line <= contents.lines().count().max(1) + 1,
            "{msg}"
        );
        assert!(
            msg.to_lowercase().contains("scene") || msg.contains("empty"),
            "{msg}"
        );
    }
}

#[test]
fn binary_garbage_file() {
    let dir = TempDir::new("garbage");
    // not UTF-8 at all
    let mut rng = XorShift(0x9e37_79b9_7f4a_7c15);
    let mut bytes: Vec<u8> = vec![0xff, 0xfe, 0x00, 0x9c];
    bytes.extend((0..4096).map(|_| rng.next() as u8));
    let path = dir.write("garbage.ron", &bytes);
    let msg = Scene::load(&path).expect_err("garbage loads").to_string();
    assert!(msg.starts_with(&path.display().to_string()), "{msg}");
    assert!(
        msg.contains("UTF-8") || msg.contains("cannot read"),
        "{msg}"
    );

    // valid UTF-8 but nonsense: a syntax error on line 1
    expect_error("«\u{1}»\u{2}\u{7f}garbage (((\n", &["expected"]);
    // an ELF-like header that happens to be UTF-8
    expect_error(
        "«\u{7f}»ELF\u{2}\u{1}\u{1}\0\0\0\0\0\0\0\0\0\u{3}\0>\0",
        &["expected"],
    );
}

/// 10 000 nested `Union([`: must be an error (or a load), never a stack overflow.
#[test]
fn deeply_nested_union() {
    let n = 10_000;
    let src = format!(
        "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)), objects: [(shape: {}Sphere(radius: 1){})])\n",
        "Union([".repeat(n),
        "])".repeat(n)
    );
    match Scene::from_source(&src, Path::new("deep.ron")) {
        Ok(s) => assert_eq!(s.objects.len(), 1),
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.starts_with("deep.ron:1:"), "{msg}");
            assert!(msg.contains("nests more than 128 levels"), "{msg}");
        }
    }
    // the same without closing brackets (a truncated file)
    let src = format!(
        "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)), objects: [(shape: {}",
        "Union([".repeat(n)
    );
    let msg = Scene::from_source(&src, Path::new("deep.ron"))
        .expect_err("a truncated file loads")
        .to_string();
    assert!(msg.starts_with("deep.ron:1:"), "{msg}");
}

/// Nesting just inside the parser's limit loads, and quickly, for every recursive node kind.
#[test]
fn nested_below_the_limit_loads() {
    let start = std::time::Instant::now();
    for (open, close) in [
        ("Union([", "])"),
        ("Transform(translate: (0.01, 0, 0), shape: ", ")"),
        ("Twist(rate: 0.01, shape: ", ")"),
        ("Bend(rate: 0.01, shape: ", ")"),
        ("Round(radius: 0.001, shape: ", ")"),
        (
            "RepeatLimited(period: (4, 4, 4), copies_each_side: (1, 0, 0), shape: ",
            ")",
        ),
    ] {
        // RON counts its own nesting; 40 levels of nodes stays well below its limit of 128.
        let n = 40;
        let src = scene(&format!(
            "    objects: [\n        (shape: {}Sphere(radius: 0.5){}),\n    ],\n",
            open.repeat(n),
            close.repeat(n)
        ));
        match Scene::from_source(&src, Path::new("nested.ron")) {
            Ok(_) => {}
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.starts_with("nested.ron:"), "{open}: {msg}");
            }
        }
    }
    assert!(
        start.elapsed().as_secs_f64() < 5.0,
        "nested loads took {:?}",
        start.elapsed()
    );
}

// ---------------------------------------------------------------------------------------------
// library level: odd characters
// ---------------------------------------------------------------------------------------------

/// RON accepts a few Unicode characters as whitespace (U+0085, U+200E, U+200F, U+2028, U+2029)
/// and nests block comments; both put non-ASCII bytes where the object locator scans. Loading
/// must not panic.
#[test]
fn unicode_whitespace_and_nested_comments_do_not_panic() {
    let inputs = [
        // U+2028 LINE SEPARATOR after the camera
        "Scene(\n    camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)),\u{2028}\n    objects: [(shape: Sphere(radius: 1))],\n)\n".to_string(),
        // U+0085 NEXT LINE before the camera
        "Scene(\u{85}camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)))\n".to_string(),
        // nested block comment holding an accented letter
        "Scene(\n    /* outer /* inner */ café */\n    camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)),\n)\n".to_string(),
        // non-ASCII inside strings and comments is fine today; keep it that way
        scene("    // façade\n    materials: { \"rouge\u{e9}\": (color: (1, 0, 0)) },\n    objects: [(name: \"bo\u{ee}te\", shape: Sphere(radius: 1), material: \"rouge\u{e9}\")],\n"),
    ];
    let mut panics = Vec::new();
    for src in &inputs {
        let r = std::panic::catch_unwind(|| {
            Scene::from_source(src, Path::new("odd.ron"))
                .map(|_| ())
                .map_err(|e| e.to_string())
        });
        match r {
            Ok(Ok(())) => {}
            Ok(Err(msg)) => assert!(msg.starts_with("odd.ron:"), "{msg}"),
            Err(_) => panics.push(src.escape_debug().to_string()),
        }
    }
    assert!(
        panics.is_empty(),
        "Scene::from_source panicked on:\n{}",
        panics.join("\n")
    );
}

/// An error after a non-ASCII comment still reports character columns.
#[test]
fn columns_count_characters() {
    expect_error(
        &scene("    objects: [\n        /* ü */ (shape: Sphere(radius: «-2»)),\n    ],\n"),
        &["> 0"],
    );
    expect_error(
        &scene(
            "    materials: { \"wei\u{df}\": (color: (1, 1, 1)) },\n    objects: [\n        (name: \"\u{fc}ber\", shape: Sphere(radius: 1), material: «\"gr\u{fc}n\"»),\n    ],\n",
        ),
        &["unknown material", "gr\u{fc}n", "wei\u{df}"],
    );
}

// ---------------------------------------------------------------------------------------------
// binary level
// ---------------------------------------------------------------------------------------------

fn hytrace(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hytrace"))
        .args(args)
        .output()
        .expect("run hytrace")
}

/// Runs `hytrace render` with `args`; it must fail plainly. Returns stderr.
fn render_fails(args: &[&std::ffi::OsStr]) -> String {
    let mut all: Vec<&std::ffi::OsStr> = vec!["render".as_ref()];
    all.extend_from_slice(args);
    let out = hytrace(&all);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        !out.status.success(),
        "hytrace {all:?} succeeded; stderr:\n{stderr}"
    );
    assert!(
        out.status.code().is_some(),
        "hytrace {all:?} was killed by a signal: {:?}",
        out.status
    );
    assert!(
        !stderr.contains("panicked"),
        "hytrace {all:?} panicked:\n{stderr}"
    );
    assert!(!stderr.trim().is_empty(), "hytrace {all:?} failed silently");
    stderr
}

fn os(s: &str) -> &std::ffi::OsStr {
    s.as_ref()
}

#[test]
fn cli_missing_scene_file() {
    let dir = TempDir::new("cli-missing");
    let scene = dir.path("does-not-exist.ron");
    let out = dir.path("out.png");
    let err = render_fails(&[scene.as_os_str(), os("-o"), out.as_os_str(), os("-q")]);
    assert!(err.contains(&scene.display().to_string()), "{err}");
    // The OS reason once, not twice (`cannot read: X: X`).
    assert_eq!(
        err.matches("os error").count(),
        1,
        "the reason is repeated: {err}"
    );
    assert!(!out.exists());
}

#[test]
fn cli_bad_scene_reports_file_line_column() {
    let dir = TempDir::new("cli-bad-scene");
    let scene = dir.write(
        "bad.ron",
        "Scene(\n    camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)),\n    objects: [(shape: Sphere(radius: -1))],\n)\n",
    );
    let out = dir.path("out.png");
    let err = render_fails(&[scene.as_os_str(), os("-o"), out.as_os_str(), os("-q")]);
    assert!(err.contains(&format!("{}:3:", scene.display())), "{err}");
    assert!(!out.exists());
}

#[test]
fn cli_mesh_path_with_an_unset_variable_names_it_and_the_place() {
    let dir = TempDir::new("cli-unset-variable");
    let scene = dir.write(
        "vars.ron",
        format!(
            "Scene(\n    camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)),\n    objects: [(mesh: \"${UNSET_VARIABLE}/m.obj\")],\n)\n"
        ),
    );
    let out = dir.path("out.png");
    let err = render_fails(&[scene.as_os_str(), os("-o"), out.as_os_str(), os("-q")]);
    assert!(err.contains(&format!("{}:3:", scene.display())), "{err}");
    assert!(
        err.contains(&format!("environment variable {UNSET_VARIABLE} is not set")),
        "{err}"
    );
    assert!(!out.exists());
}

#[test]
fn cli_zero_width_height() {
    let dir = TempDir::new("cli-width");
    let out = dir.path("out.png");
    let err = render_fails(&[os("--width"), os("0"), os("-o"), out.as_os_str(), os("-q")]);
    assert!(err.contains("width"), "{err}");
    let err = render_fails(&[os("--height"), os("0"), os("-o"), out.as_os_str(), os("-q")]);
    assert!(err.contains("height"), "{err}");
    let err = render_fails(&[
        os("--width"),
        os("100000"),
        os("-o"),
        out.as_os_str(),
        os("-q"),
    ]);
    assert!(err.contains("too large"), "{err}");
    assert!(!out.exists());
}

#[test]
fn cli_zero_spp() {
    let dir = TempDir::new("cli-spp");
    let out = dir.path("out.png");
    let err = render_fails(&[os("--spp"), os("0"), os("-o"), out.as_os_str(), os("-q")]);
    assert!(err.contains("spp"), "{err}");
    assert!(!out.exists());
}

#[test]
fn cli_zero_threads() {
    let dir = TempDir::new("cli-threads");
    let out = dir.path("out.png");
    let err = render_fails(&[
        os("--threads"),
        os("0"),
        os("--width"),
        os("16"),
        os("--height"),
        os("12"),
        os("-o"),
        out.as_os_str(),
        os("-q"),
    ]);
    assert!(err.contains("threads"), "{err}");
    assert!(!out.exists());
    // So many threads are refused before any is started (tens of thousands took minutes
    // and then failed on the system's limits).
    let err = render_fails(&[
        os("--threads"),
        os("100000"),
        os("-o"),
        out.as_os_str(),
        os("-q"),
    ]);
    assert!(err.contains("--threads 100000"), "{err}");
    assert!(!out.exists());
}

#[test]
fn cli_non_numeric_width() {
    let dir = TempDir::new("cli-abc");
    let out = dir.path("out.png");
    let err = render_fails(&[os("--width"), os("abc"), os("-o"), out.as_os_str()]);
    assert!(err.contains("abc") && err.contains("--width"), "{err}");
    let err = render_fails(&[os("--spp=-3"), os("-o"), out.as_os_str()]);
    assert!(err.contains("--spp"), "{err}");
    assert!(!out.exists());
}

#[test]
fn cli_unsupported_output_extension() {
    let dir = TempDir::new("cli-bmp");
    for name in ["out.bmp", "out", "out.png.txt"] {
        let out = dir.path(name);
        let err = render_fails(&[
            os("--width"),
            os("16"),
            os("--height"),
            os("12"),
            os("-o"),
            out.as_os_str(),
            os("-q"),
        ]);
        assert!(err.contains(name) && err.contains("png"), "{err}");
        assert!(!out.exists());
    }
}

#[test]
fn cli_output_into_missing_directory() {
    let dir = TempDir::new("cli-nodir");
    let out = dir.path("no/such/dir/out.png");
    let err = render_fails(&[
        os("--width"),
        os("16"),
        os("--height"),
        os("12"),
        os("-o"),
        out.as_os_str(),
        os("-q"),
    ]);
    assert!(err.contains(&out.display().to_string()), "{err}");
    assert!(!out.exists());
}

#[test]
fn cli_tiny_render_writes_png() {
    let dir = TempDir::new("cli-ok");
    // the built-in showcase
    let out = dir.path("showcase.png");
    let o = hytrace(&[
        os("render"),
        os("--width"),
        os("16"),
        os("--height"),
        os("12"),
        os("-o"),
        out.as_os_str(),
        os("-q"),
    ]);
    assert!(
        o.status.success(),
        "stderr:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(
        image::image_dimensions(&out).expect("read the PNG"),
        (16, 12)
    );
    let img = image::open(&out).expect("decode the PNG");
    assert_eq!((img.width(), img.height()), (16, 12));

    // a scene file, with the thread and normal options
    let scene = dir.write(
        "tiny.ron",
        "Scene(\n    image: (width: 64, height: 64),\n    camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)),\n    lights: [Ambient(intensity: 1)],\n    objects: [(shape: Sphere(radius: 1))],\n)\n",
    );
    let out = dir.path("tiny.PNG");
    let o = hytrace(&[
        os("render"),
        scene.as_os_str(),
        os("--width"),
        os("16"),
        os("--height"),
        os("12"),
        os("--threads"),
        os("1"),
        os("--normals"),
        os("tetrahedral"),
        os("-o"),
        out.as_os_str(),
        os("-q"),
    ]);
    assert!(
        o.status.success(),
        "stderr:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(
        image::image_dimensions(&out).expect("read the PNG"),
        (16, 12)
    );
}

// ---------------------------------------------------------------------------------------------
// fuzz
// ---------------------------------------------------------------------------------------------

/// Marsaglia's xorshift64: tiny, deterministic, good enough to pick mutations.
struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.0 = x;
        x
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Byte ranges of the numbers in `s` (an optional `-`, digits, `.`, exponent).
fn numbers(s: &str) -> Vec<(usize, usize)> {
    let b = s.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts = b[i].is_ascii_digit()
            || (b[i] == b'-' && b.get(i + 1).is_some_and(|c| c.is_ascii_digit()));
        let after_ident = i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_');
        if starts && !after_ident {
            let start = i;
            i += 1;
            while i < b.len()
                && (b[i].is_ascii_digit()
                    || b[i] == b'.'
                    || ((b[i] == b'e' || b[i] == b'E')
                        && b.get(i + 1)
                            .is_some_and(|c| c.is_ascii_digit() || *c == b'-')))
            {
                i += if b[i] == b'e' || b[i] == b'E' { 2 } else { 1 };
            }
            out.push((start, i.min(b.len())));
        } else {
            i += 1;
        }
    }
    out
}

/// Char-boundary-safe byte offset at or before `i`.
fn floor_boundary(s: &str, mut i: usize) -> usize {
    i = i.min(s.len());
    while !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// One random mutation of `s`, with a description.
fn mutate(s: &str, rng: &mut XorShift) -> (String, String) {
    match rng.below(6) {
        0 => {
            // delete a char range of up to 40 bytes
            let a = floor_boundary(s, rng.below(s.len()));
            let b = floor_boundary(s, a + 1 + rng.below(40));
            (
                format!("{}{}", &s[..a], &s[b..]),
                format!("delete {a}..{b}"),
            )
        }
        1 => {
            // duplicate a line
            let lines: Vec<&str> = s.split_inclusive('\n').collect();
            let k = rng.below(lines.len());
            let mut out = String::with_capacity(s.len() + lines[k].len());
            for (i, l) in lines.iter().enumerate() {
                out.push_str(l);
                if i == k {
                    out.push_str(l);
                }
            }
            (out, format!("duplicate line {}", k + 1))
        }
        2 | 3 => {
            // replace a number
            let nums = numbers(s);
            if nums.is_empty() {
                return (s.to_string(), "no number".into());
            }
            let (a, b) = nums[rng.below(nums.len())];
            let with = [
                "-1",
                "NaN",
                "1e39",
                "0",
                "-0",
                "inf",
                "1e-39",
                "4294967296",
                "0.0001",
            ][rng.below(9)];
            (
                format!("{}{with}{}", &s[..a], &s[b..]),
                format!("replace `{}` at {a} with `{with}`", &s[a..b]),
            )
        }
        5 => {
            // insert odd text: Unicode whitespace RON accepts, non-ASCII letters, comment and
            // string openers
            let odd = [
                "\u{2028}",
                "\u{85}",
                "\u{200e}",
                "é",
                "/* a /* é */ */",
                "/*",
                "//",
                "\"",
                "r#\"",
                "\\",
                "\0",
            ][rng.below(11)];
            let a = floor_boundary(s, rng.below(s.len() + 1));
            (
                format!("{}{odd}{}", &s[..a], &s[a..]),
                format!("insert {:?} at {a}", odd),
            )
        }
        _ => {
            // swap two brackets
            let brackets: Vec<usize> = s
                .bytes()
                .enumerate()
                .filter(|(_, c)| b"()[]{}".contains(c))
                .map(|(i, _)| i)
                .collect();
            if brackets.len() < 2 {
                return (s.to_string(), "no brackets".into());
            }
            let i = brackets[rng.below(brackets.len())];
            let j = brackets[rng.below(brackets.len())];
            let mut bytes = s.as_bytes().to_vec();
            bytes.swap(i, j);
            (
                String::from_utf8(bytes).expect("brackets are ASCII"),
                format!("swap brackets at {i} and {j}"),
            )
        }
    }
}

#[test]
fn fuzz_mutated_showcase_never_panics() {
    let start = std::time::Instant::now();
    // 300 cases by default; `HYTRACE_FUZZ_CASES` and `HYTRACE_FUZZ_SEED` allow longer runs.
    let env = |name: &str| std::env::var(name).ok().and_then(|v| v.parse::<u64>().ok());
    let cases = env("HYTRACE_FUZZ_CASES").unwrap_or(300);
    let mut rng = XorShift(
        env("HYTRACE_FUZZ_SEED")
            .unwrap_or(0x2545_f491_4f6c_dd1d)
            .max(1),
    );
    let (mut ok, mut err) = (0, 0);
    let mut panics = Vec::new();
    // (The panic hook is left alone: it is global, and other tests run in parallel.)
    for case in 0..cases {
        let mut src = SHOWCASE.to_string();
        let mut log = Vec::new();
        for _ in 0..1 + rng.below(3) {
            let (s, what) = mutate(&src, &mut rng);
            src = s;
            log.push(what);
        }
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            Scene::from_source(&src, Path::new("fuzz.ron"))
                .map(|_| ())
                .map_err(|e| e.to_string())
        }));
        match r {
            Ok(Ok(())) => ok += 1,
            Ok(Err(msg)) => {
                err += 1;
                if !msg.starts_with("fuzz.ron:") || place_in(&msg, "fuzz.ron").is_none() {
                    panics.push(format!(
                        "case {case} ({}): message without place: {msg}",
                        log.join("; ")
                    ));
                }
            }
            Err(p) => {
                let what = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                panics.push(format!("case {case} ({}): PANIC {what}", log.join("; ")));
            }
        }
    }
    eprintln!(
        "fuzz: {ok} loaded, {err} refused, {} problems, {:.2} s",
        panics.len(),
        start.elapsed().as_secs_f64()
    );
    assert!(panics.is_empty(), "{}", panics.join("\n"));
    assert!(err > 0, "no mutation was refused: the mutations do nothing");
}

/// Whitespace and comments that RON accepts (Unicode line separators, nested block comments
/// with non-ASCII text, line comments) inserted at the start of every line of the showcase:
/// the scene stays valid, so every variant must load, and none may panic.
#[test]
fn showcase_with_odd_whitespace_and_comments_still_loads() {
    let lines: Vec<&str> = SHOWCASE.split_inclusive('\n').collect();
    let mut problems = Vec::new();
    for insert in [
        "\u{2028}",
        "\u{85}",
        "\u{200e}",
        "/* é /* ü */ ß */",
        "// ü ( [ {\n",
    ] {
        for k in 0..lines.len() {
            let src: String = lines[..k]
                .iter()
                .copied()
                .chain([insert])
                .chain(lines[k..].iter().copied())
                .collect();
            let r = std::panic::catch_unwind(|| {
                Scene::from_source(&src, Path::new("odd.ron"))
                    .map(|_| ())
                    .map_err(|e| e.to_string())
            });
            match r {
                Ok(Ok(())) => {}
                Ok(Err(msg)) => problems.push(format!("{insert:?} before line {}: {msg}", k + 1)),
                Err(_) => problems.push(format!("{insert:?} before line {}: PANIC", k + 1)),
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn material_defined_twice() {
    expect_error(
        &scene(
            "    materials: {\n        \"red\": (color: (1, 0, 0)),\n        «\"red\"»: (color: (0, 1, 0)),\n    },\n",
        ),
        &["\"red\"", "defined twice"],
    );
}

#[test]
fn implicit_undefined_inside_its_box() {
    // sqrt of a negative number is NaN in part of the box: that would render as solid
    expect_error(
        &scene(
            "    objects: [\n        (shape: Implicit(\n            expr: «\"sqrt(x + y) - 0.5 + 0*z\"»,\n        )),\n    ],\n",
        ),
        &["expression", "NaN", "defined everywhere"],
    );
}

/// Objects whose coordinates are finite but beyond what the acceleration trees are built over
/// (10¹⁸): an SDF object there loads and renders, tested by every ray; a mesh there is refused
/// with one line naming the file. Both once panicked in the tree builder (a sphere translated
/// to 3·10³⁸, a triangle spanning ±10³⁸).
#[test]
fn coordinates_beyond_the_trees_reach() {
    let dir = TempDir::new("far");
    let far = dir.write(
        "far.ron",
        scene(
            "    objects: [\n        (shape: Sphere(radius: 1), translate: (3e38, 0, 0)),\n        \
             (shape: Box(half_extents: (1e19, 1e19, 1)), translate: (0, 0, -3)),\n    ],\n",
        ),
    );
    let png = dir.path("far.png");
    let out = hytrace(&[
        "render".as_ref(),
        far.as_os_str(),
        "--backend".as_ref(),
        "cpu".as_ref(),
        "--width".as_ref(),
        "16".as_ref(),
        "--height".as_ref(),
        "12".as_ref(),
        "-o".as_ref(),
        png.as_os_str(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // the wall 10¹⁹ wide, beyond the tree's reach, is still met by the rays
    let s = Scene::load(&far).expect("loads");
    let tracer = hytrace::trace::SceneTracer::new(&s);
    let ray = hytrace::geom::Ray::new(glam::Vec3::new(0.3, -0.2, 5.0), -glam::Vec3::Z);
    let hit = hytrace::trace::query::RayQuery::closest_hit(&tracer, &ray, 0.0, f32::INFINITY)
        .expect("the wall is hit");
    assert!((hit.t - 7.0).abs() < 1e-3, "{}", hit.t);

    for (name, obj) in [
        ("wide.obj", "v 1e38 0 0\nv -1e38 1 0\nv 0 0 1\nf 1 2 3\n"),
        ("far.obj", "v 3e37 0 0\nv 3e37 1 0\nv 3e37 0 1\nf 1 2 3\n"),
    ] {
        let mesh = dir.write(name, obj);
        let message = render_fails(&[mesh.as_os_str()]);
        assert!(
            message.lines().count() == 1
                && message.contains(name)
                && message.contains("beyond ±1e18"),
            "{message}"
        );
    }
    // a mesh the scene places beyond the reach
    let small = dir.write("small.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let placed = dir.write(
        "placed.ron",
        scene(&format!(
            "    objects: [\n        (mesh: {:?}, scale: 1e37),\n    ],\n",
            small.display().to_string()
        )),
    );
    let message = render_fails(&[placed.as_os_str()]);
    assert!(
        message.contains("placed.ron:") && message.contains("as the scene places it"),
        "{message}"
    );
}

/// `render` says what a model file held that it does not draw as asked (here a missing
/// material library), one line each on stderr, and `-q` keeps it quiet; the image is made.
#[test]
fn render_prints_the_loader_s_warnings() {
    let dir = TempDir::new("render-warnings");
    let obj = dir.write(
        "tri.obj",
        "mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    );
    let out = dir.path("tri.png");
    let args = |quiet: bool| {
        let mut a = vec![
            os("render"),
            obj.as_os_str(),
            os("--width"),
            os("16"),
            os("--height"),
            os("12"),
            os("--backend"),
            os("cpu"),
            os("-o"),
            out.as_os_str(),
        ];
        if quiet {
            a.push(os("-q"));
        }
        a
    };
    let o = hytrace(&args(false));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(
        stderr
            .lines()
            .any(|l| l.starts_with("warning: ") && l.contains("missing.mtl")),
        "{stderr}"
    );
    let o = hytrace(&args(true));
    assert!(o.status.success());
    assert!(
        o.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// A byte-order mark before the text (some Windows editors write one) is skipped, and places
/// in errors are counted from after it, as the editor shows them.
#[test]
fn byte_order_mark_is_skipped() {
    expect_ok(&format!(
        "\u{feff}{}",
        scene("    objects: [(shape: Sphere(radius: 1))],\n")
    ));
    let e = Scene::from_source(
        &format!(
            "\u{feff}{}",
            scene("    objects: [(shape: Sphere(radius: -1))],\n")
        ),
        Path::new("bom.ron"),
    )
    .unwrap_err()
    .to_string();
    assert!(e.starts_with("bom.ron:3:"), "{e}");
}

/// A camera 10²⁰ or 3·10³⁸ from its target is far, not at it: the difference of the two
/// points overflowed before it was normalised.
#[test]
fn far_cameras_look_the_right_way() {
    for far in ["1e20", "3e38"] {
        let s = expect_ok(&format!(
            "Scene(\n    camera: Perspective(position: ({far}, 0, 0), look_at: (-{far}, 0, 0)),\n    objects: [(shape: Sphere(radius: 1))],\n)\n"
        ));
        assert_eq!(s.camera.forward, glam::Vec3::NEG_X, "{far}");
    }
}

/// A bad command line is reported on one line, as every other error is (clap's own report
/// adds a tip, the usage and a pointer to `--help` on lines of their own); the values a flag
/// takes stay on it.
#[test]
fn command_line_errors_are_one_line() {
    for args in [
        &["render", "--width", "-5"][..],
        &["render", "--spp", "4294967296"],
        &["render", "--tonemap", "foo"],
        &["render", "--bogus"],
        &["validate", "--seed", "-1"],
        &["no-such-command"],
    ] {
        let argv: Vec<&std::ffi::OsStr> = args.iter().map(|a| os(a)).collect();
        let o = hytrace(&argv);
        let stderr = String::from_utf8_lossy(&o.stderr);
        let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(o.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(
            lines.len() == 1 && lines[0].starts_with("error: "),
            "{args:?}: {stderr}"
        );
    }
    let o = hytrace(&[os("render"), os("--tonemap"), os("foo")]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("reinhard"), "{stderr}");
    // Help still prints whole, on stdout, with success.
    let o = hytrace(&[os("render"), os("--help")]);
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stdout).contains("Usage:"));
}

/// A decimal number where a whole number goes is named as such, at the decimal point (the
/// parser's own message was "Expected comma").
#[test]
fn decimal_where_a_whole_number_goes() {
    let message = expect_error(
        &scene("    image: (width: 64«.5», height: 8),\n"),
        &["whole number"],
    );
    assert!(!message.contains("comma"), "{message}");
}
