//! What a window shows, drawn on the GPU (`gpu::display`, the viewer's presenter): the render
//! kernel's sums tone-mapped where they are give the picture the host makes of the same sums
//! read back (`render::view::picture`, which `hytrace render` writes), for every tone map and
//! several exposures; a picture is scaled to the window by repeating pixels; the heads-up band
//! darkens the rows under it and its text covers the picture.
//!
//! These tests need a GPU adapter (Mesa's lavapipe on machines without a GPU, installed by
//! scripts/setup.sh); a missing adapter fails them.
#![cfg(feature = "gpu")]

mod common;

use hytrace::gpu::display::{Display, HeadsUp, Shown, capture};
use hytrace::gpu::render::{GpuPasses, GpuRenderer};
use hytrace::render::RenderOptions;
use hytrace::render::output::ToneMapping;
use hytrace::render::view::{View, picture};
use hytrace::scene::Scene;
use hytrace::scene::file::ToneMap;
use image::{Rgb, RgbImage, RgbaImage};

/// The host's composition of a window, the specification the display shader follows: the
/// picture scaled by repeating pixels (window pixel x shows picture pixel ⌊x·w/W⌋), the
/// band's rows darkened to ⌊0.35·code⌋, the band's text pixels (alpha ≠ 0) drawn over.
fn composed_on_host(picture: &RgbImage, window: (u32, u32), band: &RgbaImage) -> RgbImage {
    let (w, h) = picture.dimensions();
    RgbImage::from_fn(window.0, window.1, |x, y| {
        let sx = ((x as u64 * w as u64) / window.0 as u64) as u32;
        let sy = ((y as u64 * h as u64) / window.1 as u64) as u32;
        let mut p = *picture.get_pixel(sx, sy);
        if y < band.height() {
            for c in &mut p.0 {
                *c = (*c as f32 * 0.35) as u8;
            }
            let t = band.get_pixel(x, y);
            if t[3] != 0 {
                p = Rgb([t[0], t[1], t[2]]);
            }
        }
        p
    })
}

/// A band of `rows` rows across `width` with a few text pixels in two colours.
fn band(width: u32, rows: u32) -> RgbaImage {
    RgbaImage::from_fn(width, rows, |x, y| match (x + 3 * y) % 7 {
        0 => image::Rgba([235, 235, 235, 255]),
        3 => image::Rgba([255, 120, 100, 255]),
        _ => image::Rgba([0, 0, 0, 0]),
    })
}

/// Codes that differ, and the largest difference.
fn differences(a: &RgbImage, b: &RgbImage) -> (usize, u8) {
    assert_eq!(a.dimensions(), b.dimensions());
    a.as_raw()
        .iter()
        .zip(b.as_raw())
        .fold((0, 0), |(n, most), (&x, &y)| {
            let d = x.abs_diff(y);
            (n + (d > 0) as usize, most.max(d))
        })
}

#[test]
fn sums_tone_mapped_on_the_device_equal_the_hosts_picture_of_them() {
    let ctx = common::gpu::ctx();
    let scene = Scene::from_source(
        include_str!("../assets/scenes/showcase.ron"),
        std::path::Path::new("showcase.ron"),
    )
    .expect("the showcase");
    let renderer = GpuRenderer::new(ctx);
    let prepared = renderer.prepare(ctx, &scene).expect("prepare the showcase");
    let (w, h) = (64, 48);
    let opts = RenderOptions {
        samples: 2,
        ..RenderOptions::single_sample(w, h)
    };
    let mut passes = GpuPasses::new(ctx, &renderer, w, h).expect("sums");
    for sample in 0..2 {
        renderer
            .render_pass(ctx, &prepared, &scene.camera, &opts, sample, &mut passes)
            .expect("a pass");
    }
    let sums = passes.snapshot(ctx).expect("a copy of the sums");
    let fb = passes.read(ctx).expect("read back").mean();
    let mut display = Display::new(ctx, wgpu::TextureFormat::Rgba8Unorm);
    // the window twice the picture's size and a little more: pixels repeat unevenly
    let window = (2 * w + 5, 2 * h + 3);
    let text = band(window.0, 9);
    let mut compared = 0;
    for operator in [ToneMap::Clamp, ToneMap::Reinhard, ToneMap::Aces] {
        for exposure in [-1.5, 0.0, 0.5] {
            let tone = ToneMapping { exposure, operator };
            let shown = Shown::Sums {
                buffer: &sums,
                passes: 2,
                width: w,
                height: h,
                tone,
            };
            let on_device = capture(ctx, &mut display, window, &shown, &HeadsUp { text: &text })
                .expect("capture");
            let host = composed_on_host(&picture(&fb, View::Shaded, tone, 0), window, &text);
            // the device's pow and division may round differently by an ulp, which moves a
            // code that sits on a rounding boundary by one
            let (n, most) = differences(&on_device, &host);
            let codes = host.as_raw().len();
            assert!(
                most <= 1 && n * 1000 <= codes,
                "{operator:?} at {exposure:+} EV: {n} of {codes} codes differ, by up to {most}"
            );
            compared += codes;
        }
    }
    assert!(compared > 0);
}

#[test]
fn host_pixels_are_shown_scaled_by_repetition_under_the_band() {
    let ctx = common::gpu::ctx();
    let mut display = Display::new(ctx, wgpu::TextureFormat::Rgba8Unorm);
    let picture = RgbImage::from_fn(7, 5, |x, y| Rgb([(x * 37) as u8, (y * 51) as u8, 200]));
    let rgba: Vec<u8> = picture
        .pixels()
        .flat_map(|p| [p[0], p[1], p[2], 255])
        .collect();
    for window in [(7, 5), (30, 17), (16, 40)] {
        let text = band(window.0, 4);
        let shown = Shown::Pixels {
            rgba: &rgba,
            width: 7,
            height: 5,
        };
        let on_device =
            capture(ctx, &mut display, window, &shown, &HeadsUp { text: &text }).expect("capture");
        let host = composed_on_host(&picture, window, &text);
        assert_eq!(
            differences(&on_device, &host),
            (0, 0),
            "window {window:?}: the device's composition differs from the host's"
        );
    }
}

#[test]
fn a_band_of_another_width_is_left_out_and_mismatched_sums_are_refused() {
    let ctx = common::gpu::ctx();
    let mut display = Display::new(ctx, wgpu::TextureFormat::Rgba8Unorm);
    let rgba = [10u8, 20, 30, 255];
    let shown = Shown::Pixels {
        rgba: &rgba,
        width: 1,
        height: 1,
    };
    let text = band(5, 3);
    let img = capture(ctx, &mut display, (4, 4), &shown, &HeadsUp { text: &text }).expect("ok");
    assert!(img.pixels().all(|p| p.0 == [10, 20, 30]), "no band drawn");
    // a picture whose bytes do not match its size, and sums too small for theirs
    let short = Shown::Pixels {
        rgba: &rgba[..3],
        width: 1,
        height: 1,
    };
    assert!(capture(ctx, &mut display, (4, 4), &short, &HeadsUp { text: &text }).is_err());
    let small = ctx.storage_buffer("small", &[0u8; 16], false);
    let sums = Shown::Sums {
        buffer: &small,
        passes: 1,
        width: 100,
        height: 100,
        tone: ToneMapping {
            exposure: 0.0,
            operator: ToneMap::Aces,
        },
    };
    assert!(capture(ctx, &mut display, (4, 4), &sums, &HeadsUp { text: &text }).is_err());
}
