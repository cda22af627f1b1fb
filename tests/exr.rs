//! EXR output: what [`write_exr`] writes reads back bit for bit, with the documented channel
//! names, 32-bit float samples, lossless compression and y = 0 as the top row; and the
//! `hytrace render -o x.exr --aov …` command line produces such a file from the showcase.

mod common;

use exr::prelude::{
    AnyChannels, Compression, FlatSamples, Image, Layer, ReadChannels, ReadLayers, read,
};
use glam::Vec3;
use hytrace::render::Framebuffer;
use hytrace::render::exr::{Aov, write_exr};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// A path in a fresh temporary folder; the folder goes when the value is dropped.
struct TempPath {
    path: PathBuf,
    _dir: tempfile::TempDir,
}

impl TempPath {
    fn new(tag: &str, ext: &str) -> TempPath {
        let dir = common::temp_dir(&format!("exr-{tag}"));
        TempPath {
            path: dir.path().join(format!("{tag}.{ext}")),
            _dir: dir,
        }
    }
}

/// The single layer of an EXR file, with all its channels.
fn read_layer(path: &Path) -> Layer<AnyChannels<FlatSamples>> {
    let image: Image<Layer<AnyChannels<FlatSamples>>> = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .unwrap_or_else(|e| panic!("{}: cannot read back: {e}", path.display()));
    image.layer_data
}

/// Channel name → its samples, which must be 32-bit floats.
fn channels(layer: &Layer<AnyChannels<FlatSamples>>) -> BTreeMap<String, Vec<f32>> {
    layer
        .channel_data
        .list
        .iter()
        .map(|c| {
            let name = c.name.to_string();
            match &c.sample_data {
                FlatSamples::F32(v) => (name, v.clone()),
                other => panic!("channel {name} is not 32-bit float: {other:?}"),
            }
        })
        .collect()
}

/// A 7×5 framebuffer whose every value differs by pixel and channel, with values above 1,
/// tiny (subnormal) values, zeros, negative normal components and infinite depth.
fn sample_framebuffer() -> Framebuffer {
    let (w, h) = (7u32, 5u32);
    let mut fb = Framebuffer::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let k = i as f32;
            fb.pixels[i] = Vec3::new(
                0.001 + k * 0.37,
                100.0 + k * 13.25,
                if i == 3 { 1.0e-40 } else { 1.0 / (k + 3.0) },
            );
            fb.depth[i] = if (x + y) % 3 == 0 {
                f32::INFINITY
            } else {
                1.5 + k * 0.125
            };
            fb.normal[i] = Vec3::new(-0.6 + 0.01 * k, 0.8 - 0.013 * k, -(k * 0.017));
            fb.albedo[i] = Vec3::new(
                k / 40.0,
                0.5 + k / 100.0,
                if i.is_multiple_of(4) { 0.0 } else { 0.9 },
            );
            fb.steps[i] = 1.0 + k * 2.5;
            fb.gradient[i] = 1.0;
        }
    }
    fb.pixels[0] = Vec3::ZERO;
    fb.pixels[1] = Vec3::new(f32::MIN_POSITIVE, 1.0e-30, 65504.0 * 4.0);
    fb
}

/// The written value of a named channel at pixel index `i`.
fn expected(fb: &Framebuffer, name: &str, i: usize) -> f32 {
    match name {
        "R" => fb.pixels[i].x,
        "G" => fb.pixels[i].y,
        "B" => fb.pixels[i].z,
        "depth.Z" => fb.depth[i],
        "normal.X" => fb.normal[i].x,
        "normal.Y" => fb.normal[i].y,
        "normal.Z" => fb.normal[i].z,
        "albedo.R" => fb.albedo[i].x,
        "albedo.G" => fb.albedo[i].y,
        "albedo.B" => fb.albedo[i].z,
        "steps.Y" => fb.steps[i],
        other => panic!("unexpected channel {other}"),
    }
}

const ALL_CHANNELS: [&str; 11] = [
    "B", "G", "R", "albedo.B", "albedo.G", "albedo.R", "depth.Z", "normal.X", "normal.Y",
    "normal.Z", "steps.Y",
];

#[test]
fn all_aovs_read_back_bit_identical() {
    let fb = sample_framebuffer();
    let path = TempPath::new("all", "exr");
    // Duplicates are written once.
    let aovs = [
        Aov::Steps,
        Aov::Depth,
        Aov::Normal,
        Aov::Albedo,
        Aov::Depth,
        Aov::Steps,
    ];
    write_exr(&fb, &aovs, &path.path).unwrap();

    let layer = read_layer(&path.path);
    assert_eq!(layer.size.0, 7);
    assert_eq!(layer.size.1, 5);
    assert_eq!(layer.attributes.layer_position.0, 0);
    assert_eq!(layer.attributes.layer_position.1, 0);
    let compression = layer.encoding.compression;
    assert!(
        matches!(
            compression,
            Compression::Uncompressed
                | Compression::ZIP1
                | Compression::ZIP16
                | Compression::PIZ
                | Compression::RLE
        ),
        "compression {compression:?} is not lossless for f32"
    );

    let ch = channels(&layer);
    let names: Vec<&str> = ch.keys().map(String::as_str).collect();
    assert_eq!(names, ALL_CHANNELS);
    for (name, values) in &ch {
        assert_eq!(values.len(), 35, "{name}");
        for y in 0..5usize {
            for x in 0..7usize {
                // The exr crate's flat samples are row-major with y = 0 the top row.
                let got = values[y * 7 + x];
                let want = expected(&fb, name, y * 7 + x);
                assert_eq!(
                    got.to_bits(),
                    want.to_bits(),
                    "{name} at ({x}, {y}): read {got:e}, wrote {want:e}"
                );
            }
        }
    }
    // The fixture exercises what it claims to.
    assert!(ch["depth.Z"].iter().any(|d| d.is_infinite() && *d > 0.0));
    assert!(ch["depth.Z"].iter().any(|d| d.is_finite()));
    assert!(ch["normal.X"].iter().any(|v| *v < 0.0));
    assert!(ch["G"].iter().any(|v| *v > 1.0));
    assert!(ch["R"].contains(&0.0));
    assert!(ch["B"].iter().any(|v| v.is_subnormal()));
}

#[test]
fn rgb_only_has_exactly_r_g_b() {
    let fb = sample_framebuffer();
    let path = TempPath::new("rgb", "exr");
    write_exr(&fb, &[], &path.path).unwrap();
    let ch = channels(&read_layer(&path.path));
    let names: Vec<&str> = ch.keys().map(String::as_str).collect();
    assert_eq!(names, ["B", "G", "R"]);
    for (name, values) in &ch {
        for (i, v) in values.iter().enumerate() {
            assert_eq!(v.to_bits(), expected(&fb, name, i).to_bits(), "{name}[{i}]");
        }
    }
}

#[test]
fn each_aov_alone_adds_only_its_channels() {
    let fb = sample_framebuffer();
    let cases: [(Aov, &[&str]); 4] = [
        (Aov::Depth, &["depth.Z"]),
        (Aov::Normal, &["normal.X", "normal.Y", "normal.Z"]),
        (Aov::Albedo, &["albedo.B", "albedo.G", "albedo.R"]),
        (Aov::Steps, &["steps.Y"]),
    ];
    for (aov, extra) in cases {
        let path = TempPath::new("one", "exr");
        write_exr(&fb, &[aov], &path.path).unwrap();
        let ch = channels(&read_layer(&path.path));
        let mut want: Vec<&str> = vec!["B", "G", "R"];
        want.extend_from_slice(extra);
        want.sort_unstable();
        let names: Vec<&str> = ch.keys().map(String::as_str).collect();
        assert_eq!(names, want, "{aov:?}");
    }
}

#[test]
fn unwritable_path_is_an_error_naming_the_file() {
    let fb = sample_framebuffer();
    let dir = TempPath::new("missing-dir", "d");
    let path = dir.path.join("out.exr");
    let err = write_exr(&fb, &[Aov::Depth], &path).unwrap_err();
    let msg = format!("{err:#}");
    assert!(msg.contains(&path.display().to_string()), "{msg}");
    assert!(!path.exists());
}

#[test]
fn inconsistent_framebuffer_is_an_error_not_a_panic() {
    let mut fb = sample_framebuffer();
    fb.depth.pop();
    let path = TempPath::new("short", "exr");
    let err = write_exr(&fb, &[Aov::Depth], &path.path).unwrap_err();
    assert!(format!("{err:#}").contains(&path.path.display().to_string()));
}

#[test]
fn cli_renders_showcase_with_all_aovs() {
    let path = TempPath::new("cli", "exr");
    let out = Command::new(env!("CARGO_BIN_EXE_hytrace"))
        .args(["render", "--width", "24", "--height", "16", "-q", "-o"])
        .arg(&path.path)
        .args(["--aov", "depth,normal,albedo,steps"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "hytrace failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );

    let layer = read_layer(&path.path);
    assert_eq!((layer.size.0, layer.size.1), (24, 16));
    let ch = channels(&layer);
    assert_eq!(ch.len(), 3 + 1 + 3 + 3 + 1);
    let names: Vec<&str> = ch.keys().map(String::as_str).collect();
    assert_eq!(names, ALL_CHANNELS);

    for c in ["R", "G", "B"] {
        assert!(ch[c].iter().all(|v| v.is_finite()), "{c} not finite");
    }
    let depth = &ch["depth.Z"];
    let hits = depth.iter().filter(|d| d.is_finite()).count();
    let misses = depth
        .iter()
        .filter(|d| d.is_infinite() && d.is_sign_positive())
        .count();
    assert!(hits > 0, "no pixel hit anything");
    assert!(misses > 0, "no pixel shows the sky");
    assert_eq!(hits + misses, depth.len(), "depth holds NaN or -inf");
    for (i, d) in depth.iter().enumerate() {
        if d.is_finite() {
            assert!(*d > 0.0, "depth {d} at {i}");
            let n = Vec3::new(ch["normal.X"][i], ch["normal.Y"][i], ch["normal.Z"][i]);
            assert!(
                (n.length() - 1.0).abs() < 1e-3,
                "normal {n} at pixel ({}, {}) is not unit length",
                i % 24,
                i / 24
            );
        }
    }
    assert!(ch["steps.Y"].iter().all(|s| s.is_finite() && *s >= 0.0));
}

#[test]
fn cli_aov_with_png_output_fails_cleanly() {
    let path = TempPath::new("cli-png", "png");
    let out = Command::new(env!("CARGO_BIN_EXE_hytrace"))
        .args([
            "render", "--width", "8", "--height", "8", "-q", "--aov", "depth", "-o",
        ])
        .arg(&path.path)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "succeeded: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(stderr.contains("--aov"), "{stderr}");
    assert!(!path.path.exists());
}
