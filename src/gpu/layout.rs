//! Buffer layouts shared by Rust and WGSL: each struct is declared once, in Rust, and its WGSL
//! twin is generated from the same declaration.
//!
//! [`gpu_struct!`](crate::gpu_struct) defines a `#[repr(C)]`, `bytemuck::Pod` struct, asserts
//! at compile time that its size is the stated byte count *and* the size WGSL's storage-layout
//! rules give the same field list (WGSL aligns `vec3`/`vec4` to 16 bytes, Rust's arrays of
//! `f32` to 4: the two sizes agree exactly when WGSL inserts no padding, so the field offsets
//! agree too), and emits the WGSL `struct` declaration (obvhs' `CwBvhNode` habit of a size
//! assertion next to the GPU struct; fidget's generated WGSL constants).

/// A Rust field type with a known WGSL counterpart and WGSL storage alignment and size.
pub trait WgslType {
    /// The WGSL type name.
    fn wgsl_name() -> String;
    /// Alignment in a WGSL storage buffer (WGSL spec, §"Alignment and Size").
    const ALIGN: usize;
    /// Size in a WGSL storage buffer.
    const SIZE: usize;
}

impl WgslType for u32 {
    fn wgsl_name() -> String {
        "u32".into()
    }
    const ALIGN: usize = 4;
    const SIZE: usize = 4;
}

impl WgslType for f32 {
    fn wgsl_name() -> String {
        "f32".into()
    }
    const ALIGN: usize = 4;
    const SIZE: usize = 4;
}

impl WgslType for [f32; 3] {
    fn wgsl_name() -> String {
        "vec3<f32>".into()
    }
    const ALIGN: usize = 16;
    const SIZE: usize = 12;
}

impl WgslType for [f32; 4] {
    fn wgsl_name() -> String {
        "vec4<f32>".into()
    }
    const ALIGN: usize = 16;
    const SIZE: usize = 16;
}

impl WgslType for [u32; 4] {
    fn wgsl_name() -> String {
        "vec4<u32>".into()
    }
    const ALIGN: usize = 16;
    const SIZE: usize = 16;
}

impl<const N: usize> WgslType for [[f32; 4]; N] {
    fn wgsl_name() -> String {
        format!("array<vec4<f32>, {N}>")
    }
    const ALIGN: usize = 16;
    const SIZE: usize = 16 * N;
}

impl<const N: usize> WgslType for [[u32; 4]; N] {
    fn wgsl_name() -> String {
        format!("array<vec4<u32>, {N}>")
    }
    const ALIGN: usize = 16;
    const SIZE: usize = 16 * N;
}

/// The size WGSL's storage layout gives a struct with fields of these (alignment, size) pairs:
/// each field at the next multiple of its alignment, the whole rounded up to the largest one.
pub const fn wgsl_struct_size(fields: &[(usize, usize)]) -> usize {
    let mut offset: usize = 0;
    let mut align: usize = 1;
    let mut i = 0;
    while i < fields.len() {
        let (a, s) = fields[i];
        offset = offset.div_ceil(a) * a + s;
        if a > align {
            align = a;
        }
        i += 1;
    }
    offset.div_ceil(align) * align
}

/// The alignment of a WGSL struct: the largest alignment of its fields.
pub const fn wgsl_struct_align(aligns: &[usize]) -> usize {
    let mut align = 1;
    let mut i = 0;
    while i < aligns.len() {
        if aligns[i] > align {
            align = aligns[i];
        }
        i += 1;
    }
    align
}

/// A struct shared with WGSL.
pub trait WgslStruct: bytemuck::Pod {
    /// The WGSL declaration of the struct.
    fn wgsl() -> String;
}

/// Defines a GPU buffer struct and its WGSL twin; see the module documentation.
#[macro_export]
macro_rules! gpu_struct {
    (
        $(#[$meta:meta])*
        pub struct $name:ident ($bytes:expr) {
            $( $(#[$fmeta:meta])* pub $field:ident : $ty:ty, )*
        }
    ) => {
        $(#[$meta])*
        #[repr(C)]
        #[derive(Debug, Clone, Copy, PartialEq, Default, bytemuck::Pod, bytemuck::Zeroable)]
        pub struct $name { $( $(#[$fmeta])* pub $field: $ty, )* }

        const _: () = assert!(::std::mem::size_of::<$name>() == $bytes);
        const _: () = assert!(
            $crate::gpu::layout::wgsl_struct_size(&[
                $( (<$ty as $crate::gpu::layout::WgslType>::ALIGN,
                    <$ty as $crate::gpu::layout::WgslType>::SIZE), )*
            ]) == $bytes,
            "the WGSL layout of this struct would differ from the Rust one"
        );

        impl $crate::gpu::layout::WgslType for $name {
            fn wgsl_name() -> String {
                stringify!($name).into()
            }
            const ALIGN: usize = $crate::gpu::layout::wgsl_struct_align(&[
                $( <$ty as $crate::gpu::layout::WgslType>::ALIGN, )*
            ]);
            const SIZE: usize = $bytes;
        }

        impl $crate::gpu::layout::WgslStruct for $name {
            fn wgsl() -> String {
                let mut s = format!("struct {} {{\n", stringify!($name));
                $(
                    s += &format!(
                        "    {}: {},\n",
                        stringify!($field),
                        <$ty as $crate::gpu::layout::WgslType>::wgsl_name()
                    );
                )*
                s += "}\n";
                s
            }
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wgsl_sizes_follow_the_storage_rules() {
        assert_eq!(wgsl_struct_size(&[(4, 4), (16, 16)]), 32);
        assert_eq!(wgsl_struct_size(&[(16, 12), (4, 4), (16, 12), (4, 4)]), 32);
        assert_eq!(wgsl_struct_size(&[(16, 12), (16, 12)]), 32);
        assert_eq!(wgsl_struct_size(&[(4, 4), (4, 4)]), 8);
    }
}
