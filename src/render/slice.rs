//! 2D slices of a scene's distance field: signed distance on an axis-aligned plane with iso-contours.
//!
//! The scene's field is the minimum over its objects of each object's distance tape (the same
//! tape the sphere tracer evaluates); triangle meshes (`Scene::meshes`) have no distance tape
//! and are not drawn. [`sample`] evaluates it at every pixel centre of a view of
//! an axis-aligned plane (plus a one-pixel border), and [`Field::image`] colours it in the style
//! of Inigo Quilez's 2D SDF pictures: orange outside, blue inside, brightness falling off with
//! |d|, periodic bands, thin dark iso-contours at multiples of the spacing and a white zero set.
//! Lines are anti-aliased with the field's screen-space derivative, estimated from neighbouring
//! pixels, so they are as wide in pixels whatever the scale of the field. Everything is a pure
//! function of the scene and the options: the image is the same for every run and thread count.
//!
//! # Axes
//!
//! The plane `AXIS = c` is seen from the positive side of `AXIS`, with the two other axes in
//! cyclic order x → y → z → x, so that (right, up, towards the viewer) is always a right-handed
//! frame and a picture is never mirrored:
//!
//! | plane | right | up | viewer on |
//! |---|---|---|---|
//! | `z = c` | +x | +y | +z |
//! | `x = c` | +y | +z | +x |
//! | `y = c` | +z | +x | +y |

use crate::scene::{MAX_IMAGE_SIDE, MAX_PIXELS, Scene};
use crate::sdf::interval::{Interval, IntervalRegisters, eval_box};
use crate::sdf::simplify::Simplifier;
use crate::sdf::ssa::SsaTape;
use crate::sdf::tape::{Registers, Tape};
use glam::{Vec2, Vec3};
use image::RgbImage;
use rayon::prelude::*;
use std::fmt;
use std::str::FromStr;

/// A coordinate axis of the world.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    /// The x axis.
    X,
    /// The y axis.
    Y,
    /// The z axis.
    Z,
}

impl Axis {
    /// The axis' lower-case letter.
    pub fn letter(self) -> char {
        match self {
            Axis::X => 'x',
            Axis::Y => 'y',
            Axis::Z => 'z',
        }
    }

    /// The next axis in cyclic order x → y → z → x.
    pub fn next(self) -> Axis {
        match self {
            Axis::X => Axis::Y,
            Axis::Y => Axis::Z,
            Axis::Z => Axis::X,
        }
    }

    /// The unit vector along the axis.
    pub fn unit(self) -> Vec3 {
        match self {
            Axis::X => Vec3::X,
            Axis::Y => Vec3::Y,
            Axis::Z => Vec3::Z,
        }
    }
}

/// An axis-aligned plane `axis = offset`, written `x=VALUE`, `y=VALUE` or `z=VALUE`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// The axis normal to the plane.
    pub axis: Axis,
    /// Where the plane cuts that axis (finite).
    pub offset: f32,
}

impl Plane {
    /// The plane `axis = offset`.
    pub fn new(axis: Axis, offset: f32) -> Plane {
        Plane { axis, offset }
    }

    /// The world axes drawn rightwards and upwards (see the module's *Axes*).
    pub fn image_axes(self) -> (Axis, Axis) {
        let right = self.axis.next();
        (right, right.next())
    }

    /// The world point at plane coordinates (u, v): u along the rightward axis, v along the
    /// upward one.
    pub fn point(self, uv: Vec2) -> Vec3 {
        let (right, up) = self.image_axes();
        right.unit() * uv.x + up.unit() * uv.y + self.axis.unit() * self.offset
    }
}

impl fmt::Display for Plane {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}={}", self.axis.letter(), self.offset)
    }
}

/// Why a plane could not be read (the message says what is expected).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct PlaneError(String);

impl FromStr for Plane {
    type Err = PlaneError;

    /// Reads `x=VALUE`, `y=VALUE` or `z=VALUE` (spaces around the parts and an upper-case
    /// axis letter are accepted); the value must be a finite number.
    fn from_str(s: &str) -> Result<Plane, PlaneError> {
        let err = |m: String| Err(PlaneError(m));
        let Some((axis, value)) = s.split_once('=') else {
            return err(format!(
                "`{s}` is not AXIS=VALUE: expected x=VALUE, y=VALUE or z=VALUE (e.g. z=0)"
            ));
        };
        let axis = match axis.trim().to_ascii_lowercase().as_str() {
            "x" => Axis::X,
            "y" => Axis::Y,
            "z" => Axis::Z,
            "" => return err(format!("`{s}` has no axis before `=`: expected x, y or z")),
            other => return err(format!("unknown axis `{other}`: expected x, y or z")),
        };
        let value = value.trim();
        if value.is_empty() {
            return err(format!(
                "no value after `{}=`: expected a number (e.g. {}=0)",
                axis.letter(),
                axis.letter()
            ));
        }
        let Ok(offset) = value.parse::<f32>() else {
            return err(format!("`{value}` is not a number"));
        };
        if !offset.is_finite() {
            return err(format!("the value must be a finite number (got `{value}`)"));
        }
        Ok(Plane { axis, offset })
    }
}

/// What to draw, beyond the scene and the plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SliceOptions {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Half-width of the region shown: [−size, size] horizontally around the centre, and
    /// size·height/width vertically (pixels are square).
    pub size: f32,
    /// Plane coordinates (rightward, upward) of the image centre.
    pub center: Vec2,
    /// Distance between iso-contours (and period of the bands).
    pub spacing: f32,
}

impl SliceOptions {
    /// Options for a `width`×`height` view of [−size, size] around the origin, with contours
    /// every size/10.
    pub fn new(width: u32, height: u32, size: f32) -> SliceOptions {
        SliceOptions {
            width,
            height,
            size,
            center: Vec2::ZERO,
            spacing: size / 10.0,
        }
    }

    /// Checks the options; the message names the offending option by its command-line flag.
    /// [`sample`] and [`draw`] expect options that pass.
    pub fn validate(&self) -> Result<(), String> {
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return Err(format!(
                "--width and --height must be at least 1 (got {w}×{h})"
            ));
        }
        if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE || w as u64 * h as u64 > MAX_PIXELS {
            return Err(format!(
                "image size {w}×{h} is too large (at most {MAX_IMAGE_SIDE} per side and {MAX_PIXELS} pixels)"
            ));
        }
        if !(self.size.is_finite() && self.size > 0.0) {
            return Err(format!(
                "--size must be a finite number > 0 (got {})",
                self.size
            ));
        }
        if !self.center.is_finite() {
            return Err(format!(
                "--center must be two finite numbers (got {},{})",
                self.center.x, self.center.y
            ));
        }
        if !(self.spacing.is_finite() && self.spacing > 0.0) {
            return Err(format!(
                "--spacing must be a finite number > 0 (got {})",
                self.spacing
            ));
        }
        let half = Vec2::new(self.size, self.size * h as f32 / w as f32);
        let step = self.pixel_size();
        if !((self.center.abs() + half).is_finite() && step > 0.0 && step.is_finite()) {
            return Err(format!(
                "--size {} around --center {},{} does not fit in 32-bit floats",
                self.size, self.center.x, self.center.y
            ));
        }
        Ok(())
    }

    /// The side of a pixel in plane units.
    pub fn pixel_size(&self) -> f32 {
        2.0 * self.size / self.width as f32
    }

    /// Plane coordinates of an image position in pixels (x rightwards from the left edge, y
    /// downwards from the top edge; the centre of pixel (i, j) is (i + 0.5, j + 0.5)).
    pub fn to_plane(&self, x: f32, y: f32) -> Vec2 {
        let s = self.pixel_size();
        Vec2::new(
            self.center.x + (x - 0.5 * self.width as f32) * s,
            self.center.y + (0.5 * self.height as f32 - y) * s,
        )
    }

    /// The image position in pixels of plane coordinates (the inverse of [`Self::to_plane`]).
    pub fn to_image(&self, uv: Vec2) -> Vec2 {
        let s = self.pixel_size();
        Vec2::new(
            (uv.x - self.center.x) / s + 0.5 * self.width as f32,
            0.5 * self.height as f32 - (uv.y - self.center.y) / s,
        )
    }
}

/// The scene's signed distance at `p`: the minimum of every object's distance tape (+∞ for a
/// scene without objects). `regs` is scratch space.
pub fn distance(scene: &Scene, p: Vec3, regs: &mut Registers) -> f32 {
    scene
        .objects
        .iter()
        .map(|o| o.lowered.distance.eval_in(p, regs))
        .fold(f32::INFINITY, f32::min)
}

/// The distance field sampled at the pixel centres of a view, with a one-pixel border.
#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    /// Image width (the grid is width + 2 samples wide).
    pub width: u32,
    /// Image height (the grid is height + 2 samples high).
    pub height: u32,
    /// Row-major samples, top row first; sample (i + 1, j + 1) is pixel (i, j)'s centre.
    pub values: Vec<f32>,
    /// Contour spacing (from the options).
    pub spacing: f32,
    /// Half-width of the view (from the options).
    pub size: f32,
}

impl Field {
    fn stride(&self) -> usize {
        self.width as usize + 2
    }

    /// The distance at the centre of pixel (x, y); x and y may be −1 or one past the last pixel
    /// (the border).
    pub fn at(&self, x: i64, y: i64) -> f32 {
        self.values[(y + 1) as usize * self.stride() + (x + 1) as usize]
    }

    /// The smallest and largest finite distance over the image's pixels (None if none is
    /// finite).
    pub fn range(&self) -> Option<(f32, f32)> {
        let (w, h) = (self.width as i64, self.height as i64);
        let mut r: Option<(f32, f32)> = None;
        for y in 0..h {
            for x in 0..w {
                let d = self.at(x, y);
                if d.is_finite() {
                    r = Some(r.map_or((d, d), |(a, b)| (a.min(d), b.max(d))));
                }
            }
        }
        r
    }

    /// How fast the field changes per pixel at pixel (x, y): the length of the per-axis
    /// largest one-sided difference to the neighbours (which, unlike a central difference, does
    /// not vanish on the ridges of a distance field). None where it is not finite.
    pub fn screen_gradient(&self, x: i64, y: i64) -> Option<f32> {
        let c = self.at(x, y);
        let dx = (self.at(x + 1, y) - c)
            .abs()
            .max((c - self.at(x - 1, y)).abs());
        let dy = (self.at(x, y + 1) - c)
            .abs()
            .max((c - self.at(x, y - 1)).abs());
        let g = dx.hypot(dy);
        g.is_finite().then_some(g)
    }

    /// The coloured picture (see [`colour`]).
    pub fn image(&self) -> RgbImage {
        let (w, h) = (self.width as usize, self.height as usize);
        let mut buf = vec![0u8; w * h * 3];
        buf.par_chunks_mut((w * 3).max(1))
            .enumerate()
            .for_each(|(y, row)| {
                for x in 0..w {
                    let d = self.at(x as i64, y as i64);
                    let g = self.screen_gradient(x as i64, y as i64);
                    let c = colour(d, g, self.spacing, self.size);
                    for k in 0..3 {
                        row[3 * x + k] = (c[k].clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
                    }
                }
            });
        RgbImage::from_raw(self.width, self.height, buf).expect("buffer has width×height pixels")
    }
}

/// Side in samples of the squares of the grid over which [`sample`] leaves out the objects
/// that cannot be the nearest.
const SQUARE: usize = 16;

/// Longest distance tape a slice evaluates as it is over a square of samples; a longer one is
/// specialised to the square first ([`sample`]).
const SPECIALISE_FROM: usize = 24;

/// Samples the scene's distance on `plane` at every pixel centre of the view described by
/// `opts` (which should pass [`SliceOptions::validate`]), bands of rows in parallel: the
/// values of [`distance`], bit for bit up to the sign of a zero.
///
/// In each square of [`SQUARE`]² samples only the objects whose interval enclosure over the
/// square may reach below the least upper end of all their enclosures are evaluated: the
/// others are above some object everywhere there, so the minimum is the same number. A union
/// traced as its members is a thousand objects, and evaluating each at every pixel took
/// 168 s for 20,000 boxes at 512².
///
/// An object kept whose tape is longer than [`SPECIALISE_FROM`] instructions is evaluated
/// through its program specialised to the square ([`Simplifier::specialise`]: the branches of
/// `min`, `max` and the like that the whole square takes, the rest dropped), which gives the
/// whole tape's values there up to the sign of a zero; a union of 400 spheres under a `Round`
/// took 0.66 s at 512² through its whole tape, 0.05 s so. Where a specialisation does not
/// halve the tape (a long smooth union, whose blends interval arithmetic seldom decides), the
/// object's whole tape serves the rest of the band of squares: specialising each square
/// cost such a union a third more time.
pub fn sample(scene: &Scene, plane: Plane, opts: &SliceOptions) -> Field {
    let gw = opts.width as usize + 2;
    let gh = opts.height as usize + 2;
    let mut values = vec![0.0f32; gw * gh];
    // grid row j is pixel row j − 1, centre at (j − 1) + 0.5; likewise columns
    let at = |i: usize, j: usize| plane.point(opts.to_plane(i as f32 - 0.5, j as f32 - 0.5));
    let tapes: Vec<_> = scene.objects.iter().map(|o| &o.lowered.distance).collect();
    // the programs of the long tapes, to be specialised square by square
    let programs: Vec<Option<SsaTape>> = (scene.objects.iter())
        .map(|o| {
            (o.lowered.distance.len() > SPECIALISE_FROM).then(|| o.lowered.program.distance_only())
        })
        .collect();
    values
        .par_chunks_mut(gw * SQUARE)
        .enumerate()
        .for_each(|(band, rows)| {
            let mut regs = Registers::new();
            let mut iregs = IntervalRegisters::<Interval>::new();
            let mut simplifier = Simplifier::new();
            let mut enclosures: Vec<Interval> = Vec::with_capacity(tapes.len());
            let mut specialised: Vec<Tape> = Vec::new();
            let mut kept: Vec<Kept> = Vec::with_capacity(tapes.len());
            // whether specialising each object still pays in this band
            let mut pays: Vec<bool> = programs.iter().map(Option::is_some).collect();
            let j0 = band * SQUARE;
            let band_rows = rows.len() / gw;
            for i0 in (0..gw).step_by(SQUARE) {
                let (i1, j1) = ((i0 + SQUARE).min(gw) - 1, j0 + band_rows - 1);
                let (a, b) = (at(i0, j0), at(i1, j1));
                let (lo, hi) = (a.min(b), a.max(b));
                enclosures.clear();
                enclosures.extend(tapes.iter().map(|t| eval_box(t, lo, hi, &mut iregs)));
                // (a NaN end tells nothing: such an object is kept)
                let least_top = (enclosures.iter())
                    .map(|e| e.hi)
                    .filter(|h| !h.is_nan())
                    .fold(f32::INFINITY, f32::min);
                specialised.clear();
                kept.clear();
                for (k, e) in enclosures.iter().enumerate() {
                    if !(e.lo <= least_top || e.lo.is_nan()) {
                        continue;
                    }
                    let special = (programs[k].as_ref())
                        .filter(|_| pays[k])
                        .and_then(|program| {
                            let sp = simplifier.specialise(program, lo, hi);
                            pays[k] = 2 * sp.len <= tapes[k].len();
                            if !pays[k] {
                                return None;
                            }
                            // (a program that fit whole fits shortened; if not, the whole tape)
                            sp.program.compile_distance().ok()
                        });
                    kept.push(match special {
                        Some(tape) => {
                            specialised.push(tape);
                            Kept::Specialised(specialised.len() - 1)
                        }
                        None => Kept::Whole(k),
                    });
                }
                let near: Vec<&Tape> = (kept.iter())
                    .map(|w| match *w {
                        Kept::Whole(k) => tapes[k],
                        Kept::Specialised(i) => &specialised[i],
                    })
                    .collect();
                for (dj, row) in rows.chunks_mut(gw).enumerate() {
                    for (di, v) in row[i0..=i1].iter_mut().enumerate() {
                        let p = at(i0 + di, j0 + dj);
                        *v = (near.iter())
                            .map(|t| t.eval_in(p, &mut regs))
                            .fold(f32::INFINITY, f32::min);
                    }
                }
            }
        });
    Field {
        width: opts.width,
        height: opts.height,
        values,
        spacing: opts.spacing,
        size: opts.size,
    }
}

/// The tape [`sample`] evaluates a kept object of a square by.
#[derive(Debug, Clone, Copy)]
enum Kept {
    /// The object's whole tape (object index).
    Whole(usize),
    /// Its tape specialised to the square (index into the square's specialised tapes).
    Specialised(usize),
}

/// Draws the scene's signed distance on `plane`: [`sample`], then [`Field::image`].
pub fn draw(scene: &Scene, plane: Plane, opts: &SliceOptions) -> RgbImage {
    sample(scene, plane, opts).image()
}

/// Base colour where the distance is positive (outside every object).
pub const OUTSIDE: [f32; 3] = [0.94, 0.58, 0.26];
/// Base colour where the distance is negative or zero (inside).
pub const INSIDE: [f32; 3] = [0.30, 0.58, 0.95];
/// Width in pixels of the dark iso-contours.
pub const CONTOUR_WIDTH: f32 = 1.5;
/// Width in pixels of the white zero-set line.
pub const ZERO_WIDTH: f32 = 2.0;

/// Coverage of a line `width` pixels wide by a pixel whose centre is `e` pixels from it: a box
/// filter over one pixel, 1 within (width − 1)/2 and 0 beyond (width + 1)/2.
fn line_coverage(e: f32, width: f32) -> f32 {
    (0.5 * width + 0.5 - e).clamp(0.0, 1.0)
}

/// The display colour (sRGB-encoded, each in [0, 1]) of a pixel where the field is `d` and
/// changes by `g` per pixel (None if unknown), for contours every `spacing` in a view of
/// half-width `size`:
///
/// * base colour [`OUTSIDE`] for d > 0, [`INSIDE`] otherwise;
/// * times 0.3 + 0.7·exp(−2|d|/size): brightness falls off away from the surface;
/// * times 0.8 + 0.2·cos(2π·d/spacing): bands, brightest at the contours;
/// * dark lines [`CONTOUR_WIDTH`] pixels wide at the non-zero multiples of `spacing`;
/// * a white line [`ZERO_WIDTH`] pixels wide at d = 0.
///
/// A line's distance in pixels from the pixel is |d − level|/g. Where contours would come closer
/// than 6 pixels, bands and contours fade out (to their average) instead of aliasing. A NaN
/// distance is grey; ±∞ (no object) is the dimmest shade of its side.
pub fn colour(d: f32, g: Option<f32>, spacing: f32, size: f32) -> [f32; 3] {
    if d.is_nan() {
        return [0.5, 0.5, 0.5];
    }
    let base = if d > 0.0 { OUTSIDE } else { INSIDE };
    if d.is_infinite() {
        return base.map(|c| 0.3 * c);
    }
    let g = g.filter(|g| *g > 0.0);
    // Contour density: how many pixels apart consecutive levels are (∞ if unknown/flat).
    let gap = g.map_or(f32::INFINITY, |g| spacing / g);
    let fade = ((gap - 3.0) / 3.0).clamp(0.0, 1.0);
    let falloff = 0.3 + 0.7 * (-2.0 * d.abs() / size).exp();
    let band = 0.8 + 0.2 * fade * (std::f32::consts::TAU * d / spacing).cos();
    let mut c = base.map(|b| b * falloff * band);
    if let Some(g) = g {
        let level = (d / spacing).round();
        if level != 0.0 {
            let e = (d - level * spacing).abs() / g;
            let a = 0.8 * fade * line_coverage(e, CONTOUR_WIDTH);
            c = c.map(|v| v * (1.0 - a) + 0.1 * v * a);
        }
        let a = line_coverage(d.abs() / g, ZERO_WIDTH);
        c = c.map(|v| v * (1.0 - a) + a);
    } else if d == 0.0 {
        c = [1.0; 3];
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planes_parse_and_reject() {
        assert_eq!("z=0".parse::<Plane>(), Ok(Plane::new(Axis::Z, 0.0)));
        assert_eq!(" X = -1.5 ".parse::<Plane>(), Ok(Plane::new(Axis::X, -1.5)));
        assert_eq!("y=2e-1".parse::<Plane>(), Ok(Plane::new(Axis::Y, 0.2)));
        for bad in [
            "w=1", "z=", "z=abc", "z=NaN", "z=inf", "z", "=1", "", "z=1=2",
        ] {
            assert!(bad.parse::<Plane>().is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn axes_are_right_handed() {
        for axis in [Axis::X, Axis::Y, Axis::Z] {
            let p = Plane::new(axis, 0.0);
            let (r, u) = p.image_axes();
            assert_eq!(r.unit().cross(u.unit()), axis.unit());
        }
        let p = Plane::new(Axis::Y, 3.0);
        assert_eq!(p.point(Vec2::new(1.0, 2.0)), Vec3::new(2.0, 3.0, 1.0));
    }

    #[test]
    fn pixel_mapping_round_trips() {
        let o = SliceOptions {
            center: Vec2::new(0.5, -1.0),
            ..SliceOptions::new(200, 100, 2.0)
        };
        assert_eq!(o.to_plane(0.0, 0.0), Vec2::new(-1.5, 0.0));
        assert_eq!(o.to_plane(100.0, 50.0), o.center);
        let q = Vec2::new(0.3, -0.7);
        assert!((o.to_plane(o.to_image(q).x, o.to_image(q).y) - q).length() < 1e-5);
    }

    #[test]
    fn options_are_checked() {
        assert!(SliceOptions::new(64, 64, 1.0).validate().is_ok());
        assert!(SliceOptions::new(0, 64, 1.0).validate().is_err());
        assert!(SliceOptions::new(64, 64, 0.0).validate().is_err());
        assert!(SliceOptions::new(64, 64, f32::NAN).validate().is_err());
        assert!(SliceOptions::new(64, 64, 3e38).validate().is_err());
        assert!(
            SliceOptions::new(MAX_IMAGE_SIDE + 1, 1, 1.0)
                .validate()
                .is_err()
        );
    }

    #[test]
    fn colours_by_side() {
        let out = colour(0.5, Some(0.01), 0.25, 2.5);
        let inside = colour(-0.5, Some(0.01), 0.25, 2.5);
        assert!(out[0] > out[2] && inside[2] > inside[0]);
        assert_eq!(colour(0.0, Some(0.01), 0.25, 2.5), [1.0; 3]);
        assert_eq!(colour(f32::NAN, None, 0.25, 2.5), [0.5; 3]);
        assert!(
            colour(f32::INFINITY, None, 0.25, 2.5)
                .iter()
                .all(|c| c.is_finite())
        );
    }
}
