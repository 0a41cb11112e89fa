//! The command line's names of the library's choices (`--interp`, `--format`, `--exr-type`,
//! `--exr-compression`): clap `ValueEnum`s here, converted to the library's plain enums at
//! the boundary, so that the library does not depend on clap. The doc comments are the help
//! text of each value.

/// Defines a clap value enum mirroring the library enum `$lib` variant for variant, with
/// `From` both ways.
macro_rules! value_enum {
    ($(#[$m:meta])* $name:ident => $lib:path { $($(#[$vm:meta])* $v:ident),* $(,)? }) => {
        $(#[$m])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
        pub enum $name {
            $($(#[$vm])* $v),*
        }
        impl From<$name> for $lib {
            fn from(v: $name) -> $lib {
                match v {
                    $($name::$v => <$lib>::$v),*
                }
            }
        }
        impl From<$lib> for $name {
            fn from(v: $lib) -> $name {
                match v {
                    $(<$lib>::$v => $name::$v),*
                }
            }
        }
    };
}

value_enum! {
    /// How a table source is evaluated between its samples (`crate::source::Lookup`).
    LookupArg => crate::source::Lookup {
        /// Multilinear in warped index space (docs/parameterizations.md).
        Linear,
        /// The nearest sample.
        Nearest,
        /// The MERL reference reader's nearest-lower-bin rule, exactly (MERL-grid tables only).
        Merl,
    }
}

value_enum! {
    /// How a table is evaluated between its samples (`crate::table::Interp`).
    InterpArg => crate::table::Interp {
        /// The sample whose cell contains the query (rounded in warped index space).
        Nearest,
        /// Multilinear in warped index space: periodic φ, clamped θ ends, invalid neighbours
        /// dropped and the remaining weights renormalized.
        Linear,
    }
}

value_enum! {
    /// A format name, as `--format` takes it (`crate::io::FormatName`).
    FormatArg => crate::io::FormatName {
        /// brdfpack's native `.bpk`.
        Native,
        /// OpenEXR image (`.exr`).
        Exr,
        /// MERL `.binary` (90×90×180 halfdiff grid, RGB).
        Merl,
        /// MDL `.mbsdf` (spherical3 grid, scalar or RGB).
        Mbsdf,
        /// RGL `.bsdf` for Mitsuba 3 / pbrt-v4 `measured` (written by `convert` only).
        Rgl,
    }
}

value_enum! {
    /// Storage type of the value channels (`crate::io::exr::ExrSampleType`).
    ExrTypeArg => crate::io::exr::ExrSampleType {
        /// 32-bit float: the table's samples exactly.
        F32,
        /// 16-bit float: lossy (11 significant bits); values above 65504 are scaled by a power
        /// of two recorded in the header.
        F16,
    }
}

value_enum! {
    /// EXR compression (`crate::io::exr::ExrCompression`).
    ExrCompressionArg => crate::io::exr::ExrCompression {
        None,
        Rle,
        /// zlib, one scanline per block.
        Zips,
        /// zlib, 16 scanlines per block (the default: small and lossless).
        Zip,
        Piz,
        /// Lossy for f32 (rounds to 24-bit floats); lossless for f16 and u32.
        Pxr24,
    }
}
