//! `hytrace slice`: 2D pictures of the distance field on an axis-aligned plane — colours on the
//! right side of the surface, the white zero line on the surface, every shipped scene on three
//! planes, the axis convention, determinism, and the command line's errors.

mod common;

use glam::{Vec2, Vec3};
use hytrace::render::slice::{Axis, Plane, SliceOptions, draw, sample};
use hytrace::scene::Scene;
use image::RgbImage;
use std::path::{Path, PathBuf};
use std::process::Command;

fn scene(objects: &str) -> Scene {
    let src = format!(
        "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0)), objects: [{objects}])"
    );
    Scene::from_source(&src, Path::new("<test>")).expect("test scene loads")
}

fn unit_sphere() -> Scene {
    scene("(shape: Sphere(radius: 1))")
}

/// The pixel of `img` containing plane point `uv`.
fn pixel_at(img: &RgbImage, opts: &SliceOptions, uv: Vec2) -> [u8; 3] {
    let p = opts.to_image(uv);
    img.get_pixel(p.x.floor() as u32, p.y.floor() as u32).0
}

fn is_inside_colour(c: [u8; 3]) -> bool {
    c[2] > c[0]
}

fn is_outside_colour(c: [u8; 3]) -> bool {
    c[0] > c[2]
}

#[test]
fn inside_is_blue_and_outside_is_orange() {
    let opts = SliceOptions::new(128, 128, 2.0);
    let img = draw(&unit_sphere(), Plane::new(Axis::Z, 0.0), &opts);
    assert_eq!(img.dimensions(), (128, 128));
    let centre = img.get_pixel(64, 64).0;
    assert!(is_inside_colour(centre), "centre {centre:?}");
    for uv in [(0.3, 0.2), (-0.5, 0.1), (0.0, -0.7), (0.55, 0.55)] {
        let c = pixel_at(&img, &opts, Vec2::from(uv));
        assert!(is_inside_colour(c), "{uv:?} should be inside: {c:?}");
    }
    for (x, y) in [(0, 0), (127, 0), (0, 127), (127, 127)] {
        let c = img.get_pixel(x, y).0;
        assert!(is_outside_colour(c), "corner ({x}, {y}) {c:?}");
    }
    for uv in [(1.3, 0.0), (-1.5, 0.4), (0.0, 1.8), (0.9, -0.9)] {
        let c = pixel_at(&img, &opts, Vec2::from(uv));
        assert!(is_outside_colour(c), "{uv:?} should be outside: {c:?}");
    }
}

#[test]
fn zero_line_lies_on_the_circle() {
    let opts = SliceOptions::new(128, 128, 2.0); // 32 px per unit
    let img = draw(&unit_sphere(), Plane::new(Axis::Z, 0.0), &opts);
    for k in 0..16 {
        let a = k as f32 * std::f32::consts::TAU / 16.0 + 0.1;
        let dir = Vec2::new(a.cos(), a.sin());
        let on = pixel_at(&img, &opts, dir);
        assert!(
            on.iter().all(|&c| c >= 190),
            "angle {a}: the pixel on the circle is not white: {on:?}"
        );
        // A few pixels off the circle, on either side, the line is gone.
        for r in [0.9, 1.1] {
            let off = pixel_at(&img, &opts, dir * r);
            assert!(
                off.iter().any(|&c| c < 150),
                "angle {a}, radius {r}: unexpected white {off:?}"
            );
        }
    }
}

#[test]
fn field_is_the_minimum_over_objects() {
    let s = scene(
        "(shape: Sphere(radius: 0.5), translate: (-1, 0, 0)), \
         (shape: Box(half_extents: (0.5, 0.5, 0.5)), translate: (1, 0, 0))",
    );
    let opts = SliceOptions::new(8, 4, 2.0);
    let field = sample(&s, Plane::new(Axis::Z, 0.0), &opts);
    for y in -1..=4i64 {
        for x in -1..=8i64 {
            let uv = opts.to_plane(x as f32 + 0.5, y as f32 + 0.5);
            let sphere = (uv - Vec2::new(-1.0, 0.0)).length() - 0.5;
            let q = (uv - Vec2::new(1.0, 0.0)).abs() - Vec2::splat(0.5);
            let boxd = q.max(Vec2::ZERO).length() + q.x.max(q.y).min(0.0);
            let want = sphere.min(boxd);
            assert!((field.at(x, y) - want).abs() < 1e-5, "({x}, {y})");
        }
    }
}

/// 300 small boxes of many orientations on a ring, as shapes of a scene file.
fn rotated_boxes() -> Vec<String> {
    (0..300)
        .map(|i| {
            let a = i as f32 * 0.37;
            format!(
                "Transform(translate: ({:.3}, {:.3}, {:.3}), rotate: ({}, {}, 0), \
                 shape: Box(half_extents: (0.08, 0.05, 0.1)))",
                1.8 * a.cos(),
                -0.5 + 0.004 * i as f32,
                1.8 * a.sin(),
                i % 90,
                i % 45
            )
        })
        .collect()
}

/// Checks every sample of the slices of `s` on three planes against [`distance`] at the same
/// point, with `same(slice's value, distance's value)`.
fn slices_match_the_distance(s: &Scene, opts: &SliceOptions, same: impl Fn(f32, f32) -> bool) {
    let mut regs = Default::default();
    for plane in [
        Plane::new(Axis::Y, -0.3),
        Plane::new(Axis::Z, 0.2),
        Plane::new(Axis::X, 1.1),
    ] {
        let field = sample(s, plane, opts);
        for y in -1..=opts.height as i64 {
            for x in -1..=opts.width as i64 {
                let uv = opts.to_plane(x as f32 + 0.5, y as f32 + 0.5);
                let want = hytrace::render::slice::distance(s, plane.point(uv), &mut regs);
                let got = field.at(x, y);
                assert!(same(got, want), "{plane} ({x}, {y}): {got} against {want}");
            }
        }
    }
}

/// One object with a long tape (a union of 300 rotated boxes under a `Round`, which keeps it
/// one object; a smooth chain beside it) is evaluated square by square through its tape
/// specialised to the square: the values stay those of the whole tape at every pixel, up to
/// the sign of a zero.
#[test]
fn tapes_specialised_to_squares_change_no_value() {
    let boxes = rotated_boxes();
    let chain: Vec<String> = (0..40)
        .map(|i| {
            format!(
                "Transform(translate: ({:.3}, 0.3, {:.3}), shape: Sphere(radius: 0.15))",
                -1.5 + 0.075 * i as f32,
                0.5 * (i as f32 * 0.4).sin()
            )
        })
        .collect();
    let s = scene(&format!(
        "(shape: Round(radius: 0.02, shape: Union([{}]))), \
         (shape: SmoothUnion(k: 0.1, shapes: [{}]))",
        boxes.join(", "),
        chain.join(", ")
    ));
    assert_eq!(s.objects.len(), 2, "each a single object");
    assert!(s.objects.iter().all(|o| o.lowered.distance.len() > 400));
    let opts = SliceOptions::new(96, 64, 2.5);
    // (a specialised tape may give −0 where the whole one gives +0)
    slices_match_the_distance(&s, &opts, |got, want| {
        got == want || (got.is_nan() && want.is_nan())
    });
}

/// The slice leaves out, square by square, the objects whose interval enclosure cannot reach
/// the least upper end of the others': the values stay those of every object evaluated at
/// every pixel, bit for bit. A union of 300 rotated boxes (traced as its members), a smooth
/// union, an implicit and a ground plane, on three planes.
#[test]
fn objects_left_out_by_their_enclosures_change_no_value() {
    let boxes = rotated_boxes();
    let s = scene(&format!(
        "(shape: Union([{}])), \
         (shape: SmoothUnion(k: 0.3, shapes: [Sphere(radius: 0.5), \
            Transform(translate: (0.6, 0, 0), shape: Sphere(radius: 0.4))])), \
         (translate: (0, 0.8, 0), shape: Implicit(expr: \"x*x + y*y*2 + z*z - 0.3\", \
            half_extents: (1, 1, 1))), \
         (shape: Plane(normal: (0, 1, 0), offset: -1))",
        boxes.join(", ")
    ));
    assert!(s.objects.len() > 300, "the union is traced as its members");
    let opts = SliceOptions::new(70, 45, 2.5);
    slices_match_the_distance(&s, &opts, |got, want| got.to_bits() == want.to_bits());
}

#[test]
fn axes_follow_the_documented_convention() {
    // y = 0 is seen from +y: z rightwards, x upwards.
    let s = scene("(shape: Sphere(radius: 0.4), translate: (1, 0, 0))");
    let opts = SliceOptions::new(64, 64, 2.0);
    let img = draw(&s, Plane::new(Axis::Y, 0.0), &opts);
    assert!(is_inside_colour(pixel_at(&img, &opts, Vec2::new(0.0, 1.0))));
    assert!(is_outside_colour(pixel_at(
        &img,
        &opts,
        Vec2::new(1.0, 0.0)
    )));
    // x = 0.0 is seen from +x: y rightwards, z upwards.
    let s = scene("(shape: Sphere(radius: 0.4), translate: (0, 1, 0))");
    let img = draw(&s, Plane::new(Axis::X, 0.0), &opts);
    assert!(is_inside_colour(pixel_at(&img, &opts, Vec2::new(1.0, 0.0))));
    assert!(is_outside_colour(pixel_at(
        &img,
        &opts,
        Vec2::new(0.0, 1.0)
    )));
    // z = c moves the plane: a sphere of radius 1 sliced at z = 0.8 is a circle of radius 0.6.
    let img = draw(&unit_sphere(), Plane::new(Axis::Z, 0.8), &opts);
    assert!(is_inside_colour(pixel_at(
        &img,
        &opts,
        Vec2::new(0.45, 0.0)
    )));
    assert!(is_outside_colour(pixel_at(
        &img,
        &opts,
        Vec2::new(0.75, 0.0)
    )));
}

#[test]
fn same_image_for_any_thread_count() {
    let s = Scene::load(Path::new("assets/scenes/showcase.ron")).unwrap();
    let opts = SliceOptions {
        center: Vec2::new(0.5, 0.2),
        ..SliceOptions::new(96, 64, 5.0)
    };
    let with = |n: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
            .install(|| draw(&s, Plane::new(Axis::Z, 0.3), &opts))
    };
    let one = with(1);
    assert_eq!(one, with(4));
    assert_eq!(one, with(3));
}

fn scene_files() -> Vec<PathBuf> {
    let mut v = Vec::new();
    for dir in ["assets/scenes", "assets/scenes/slices"] {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "ron") {
                v.push(p);
            }
        }
    }
    v.sort();
    v
}

#[test]
fn every_shipped_scene_slices_on_three_planes() {
    let files = scene_files();
    assert!(files.len() >= 12, "{files:?}");
    for name in [
        "circle",
        "square",
        "squircle",
        "union",
        "intersection",
        "subtraction",
    ] {
        let p = PathBuf::from(format!("assets/scenes/slices/{name}.ron"));
        assert!(files.contains(&p), "{} missing", p.display());
    }
    let opts = SliceOptions::new(64, 64, 3.0);
    for f in &files {
        let s = Scene::load(f).unwrap_or_else(|e| panic!("{e}"));
        for axis in [Axis::X, Axis::Y, Axis::Z] {
            let field = sample(&s, Plane::new(axis, 0.0), &opts);
            assert!(
                field.range().is_some(),
                "{}: no finite distance on {axis:?} = 0",
                f.display()
            );
            assert_eq!(field.image().dimensions(), (64, 64));
        }
    }
}

#[test]
fn thesis_figures_have_their_zero_sets() {
    // On z = 0 every slice scene is inside at a known point and outside at another.
    let cases = [
        ("circle", (0.0, 0.0), (0.0, 1.1)),
        ("square", (0.95, 0.95), (1.05, 0.0)),
        ("squircle", (0.0, 0.95), (0.9, 0.9)),
        ("union", (-1.2, -1.1), (1.2, -1.1)),
        ("intersection", (0.2, 0.2), (-1.2, -1.1)),
        ("subtraction", (-1.2, -1.1), (0.45, 0.35)),
    ];
    let opts = SliceOptions::new(1, 1, 1.0);
    for (name, inside, outside) in cases {
        let s = Scene::load(Path::new(&format!("assets/scenes/slices/{name}.ron"))).unwrap();
        let d = |uv: (f32, f32)| {
            let o = SliceOptions {
                center: Vec2::from(uv),
                ..opts
            };
            sample(&s, Plane::new(Axis::Z, 0.0), &o).at(0, 0)
        };
        assert!(d(inside) < 0.0, "{name}: {inside:?} should be inside");
        assert!(d(outside) > 0.0, "{name}: {outside:?} should be outside");
    }
    // The squircle crosses zero at (±1, 0) and (0, ±1).
    let s = Scene::load(Path::new("assets/scenes/slices/squircle.ron")).unwrap();
    for p in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y] {
        let d = hytrace::render::slice::distance(&s, p, &mut Default::default());
        assert!(d.abs() < 1e-5, "squircle at {p}: {d}");
    }
}

// ---- the command line ----

fn hytrace(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_hytrace"))
        .args(args)
        .output()
        .expect("runs hytrace")
}

#[test]
fn cli_rejects_bad_input() {
    let dir_tmp = common::temp_dir("slice-bad");
    let dir = dir_tmp.path().to_path_buf();
    let out = dir.join("out.png");
    let out = out.to_str().unwrap();
    let circle = "assets/scenes/slices/circle.ron";
    let cases: &[(&[&str], &str)] = &[
        (&["--plane", "w=1"], "--plane"),
        (&["--plane", "z="], "--plane"),
        (&["--plane", "z=abc"], "--plane"),
        (&["--plane", "z=NaN"], "--plane"),
        (&["--plane", "z=inf"], "--plane"),
        (&["--plane", "z"], "--plane"),
        (&["--plane", "=1"], "--plane"),
        (&["--plane", "-1"], "--plane"),
        (&["--size", "0"], "--size"),
        (&["--size", "-1"], "--size"),
        (&["--size", "NaN"], "--size"),
        (&["--size", "inf"], "--size"),
        (&["--size", "3e38"], "--size"),
        (&["--spacing", "0"], "--spacing"),
        (&["--spacing", "-0.5"], "--spacing"),
        (&["--spacing", "NaN"], "--spacing"),
        (&["--center", "1"], "--center"),
        (&["--center", "a,b"], "--center"),
        (&["--center", "1,2,3"], "--center"),
        (&["--center", "0,inf"], "--center"),
        (&["--width", "0"], "--width"),
        (&["--height", "0"], "--height"),
        (&["--width", "20000"], "too large"),
        (&["--width", "16384", "--height", "16384"], "too large"),
        (&["--width", "-3"], ""),
        (&["--width", "abc"], ""),
    ];
    let check = |args: Vec<&str>, needle: &str| {
        let o = hytrace(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
        assert!(
            err.contains(needle),
            "{args:?}: {err:?} does not mention {needle:?}"
        );
    };
    for (extra, needle) in cases {
        let mut args = vec!["slice", circle, "-q", "-o", out];
        args.extend_from_slice(extra);
        check(args, needle);
    }
    assert!(!Path::new(out).exists(), "a failed run wrote {out}");
    // A missing scene and outputs that are not PNG.
    check(
        vec!["slice", "no/such/scene.ron", "-o", out],
        "no/such/scene.ron",
    );
    let jpg = dir.join("out.jpg");
    check(vec!["slice", circle, "-o", jpg.to_str().unwrap()], "png");
    let bare = dir.join("out");
    check(vec!["slice", circle, "-o", bare.to_str().unwrap()], "png");
    // An unwritable output.
    let nowhere = dir.join("no-such-dir").join("x.png");
    check(
        vec!["slice", circle, "-o", nowhere.to_str().unwrap()],
        "x.png",
    );
}

#[test]
fn cli_writes_a_png_of_the_requested_size() {
    let dir_tmp = common::temp_dir("slice-ok");
    let dir = dir_tmp.path().to_path_buf();
    let out = dir.join("slice.png");
    let o = hytrace(&[
        "slice",
        "assets/scenes/slices/union.ron",
        "--plane",
        "z=0",
        "--size",
        "2.5",
        "--center",
        "-0.5,0.25",
        "--width",
        "40",
        "--height",
        "24",
        "-o",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("40×24"), "summary line: {err}");
    let img = image::open(&out).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (40, 24));
    // Quiet, other plane, default size, negative plane offset.
    std::fs::remove_file(&out).unwrap();
    let o = hytrace(&[
        "slice",
        "assets/scenes/slices/circle.ron",
        "--plane",
        "x=-0.5",
        "--width",
        "17",
        "--height",
        "9",
        "-q",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(o.stderr.is_empty(), "-q printed something");
    assert_eq!(image::open(&out).unwrap().to_rgb8().dimensions(), (17, 9));
}
