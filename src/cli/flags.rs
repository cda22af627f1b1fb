//! The command line's spelling of library enums: `clap::ValueEnum` mirrors with conversions.
//!
//! The library types stay free of clap (command-line concerns live in `cli/`), so each flag
//! that takes one of them takes its mirror here instead. A mirror's doc comments are clap's
//! help for each value, and its variant names, in kebab case, are the values.

use hytrace::render::exr::Aov;
use hytrace::render::view::View;
use hytrace::scene::file::{BuildQuality, NormalMethod, ToneMap};

/// Declares `$name`, a `clap::ValueEnum` with the listed variants, as the command-line mirror
/// of the library enum `$lib`, with `From` conversions both ways. The variants are listed once,
/// here; both conversions are exhaustive matches, so a variant added to either enum alone is a
/// compile error rather than a value the command line silently lacks.
macro_rules! mirror_enum {
    (
        $(#[$meta:meta])*
        $vis:vis enum $name:ident mirrors $lib:ty {
            $( $(#[$variant_meta:meta])* $variant:ident, )+
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
        $vis enum $name {
            $( $(#[$variant_meta])* $variant, )+
        }

        impl From<$name> for $lib {
            fn from(value: $name) -> Self {
                match value {
                    $( $name::$variant => Self::$variant, )+
                }
            }
        }

        impl From<$lib> for $name {
            fn from(value: $lib) -> Self {
                // a path fragment cannot be extended with `::Variant`, an alias can
                type Lib = $lib;
                match value {
                    $( Lib::$variant => Self::$variant, )+
                }
            }
        }
    };
}

mirror_enum! {
    /// `--view`: which picture to make of a render.
    pub enum ViewArg mirrors View {
        /// The shaded image (tone-mapped radiance).
        Shaded,
        /// Normals as colours: (n + 1)/2.
        Normals,
        /// Distance to the first hit, near = bright, with a legend.
        Depth,
        /// Sphere-tracing steps per pixel as a heatmap with a legend (Hart 1996's "pixels
        /// coloured by number of steps").
        Steps,
        /// |∇f| at the hit: green = 1 (exact), blue < 1 (conservative bound), red > 1 (a field
        /// that over-estimates distance and may step through surfaces), with a legend.
        Gradient,
    }
}

mirror_enum! {
    /// `--tonemap`: the tone-mapping operator.
    pub enum ToneMapArg mirrors ToneMap {
        /// Clip each channel to [0, 1].
        Clamp,
        /// Reinhard's x/(1 + x) per channel (Reinhard et al. 2002).
        Reinhard,
        /// Narkowicz's fit of the ACES filmic curve (2015), per channel.
        Aces,
    }
}

mirror_enum! {
    /// `--aov`: an auxiliary EXR channel set.
    pub enum AovArg mirrors Aov {
        /// Distance to the first hit along the camera ray, in scene units (`depth.Z`); +∞ where
        /// every sample of the pixel missed (sky). EXR floats hold infinity, so a miss reads
        /// back as `f32::INFINITY`; over a pixel's samples the nearest hit is kept.
        Depth,
        /// First-hit surface normal in world space (`normal.X`, `normal.Y`, `normal.Z`),
        /// averaged over the pixel's samples (so not renormalised where samples disagree); 0 on
        /// a miss.
        Normal,
        /// First-hit albedo, linear (`albedo.R`, `albedo.G`, `albedo.B`); 0 on a miss.
        Albedo,
        /// Sphere-tracing steps of the camera ray, averaged over the pixel's samples
        /// (`steps.Y`).
        Steps,
    }
}

mirror_enum! {
    /// `--normals`: how normals are estimated from the field.
    pub enum NormalsArg mirrors NormalMethod {
        /// Central differences: 6 evaluations.
        Central,
        /// Tetrahedral 4-tap estimate (Quilez, "normals for an SDF").
        Tetrahedral,
    }
}

mirror_enum! {
    /// `--bvh`: the mesh BVH build quality.
    pub enum BvhArg mirrors BuildQuality {
        /// Binned SAH splits in parallel, collapsed to eight children per node by the SAH.
        Fast,
        /// As `fast`, with spatial pre-splits of large triangles (the default).
        Medium,
        /// obvhs's PLOC with reinsertion and the spatial pre-splits.
        High,
        /// As `high`, with reinsertion over every node: several times `medium`'s build time.
        Highest,
    }
}

/// Converts each value of a repeated flag to its library type.
pub fn convert_all<A: Copy + Into<L>, L>(values: &[A]) -> Vec<L> {
    values.iter().map(|&v| v.into()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::ValueEnum;

    /// Every mirror round-trips through its library type, and its command-line names are the
    /// library variants' names in kebab case (what clap derived when the library types
    /// carried the derive themselves).
    #[test]
    fn mirrors_round_trip_with_kebab_case_names() {
        fn check<A, L>()
        where
            A: ValueEnum + Copy + PartialEq + std::fmt::Debug + Into<L> + From<L>,
            L: std::fmt::Debug,
        {
            for &a in A::value_variants() {
                let lib: L = a.into();
                let name = a.to_possible_value().unwrap().get_name().to_string();
                let expected = format!("{lib:?}").to_ascii_lowercase();
                assert_eq!(name, expected, "{a:?}");
                assert_eq!(A::from(lib), a);
            }
        }
        check::<ViewArg, View>();
        check::<ToneMapArg, ToneMap>();
        check::<AovArg, Aov>();
        check::<NormalsArg, NormalMethod>();
        check::<BvhArg, BuildQuality>();
    }
}
