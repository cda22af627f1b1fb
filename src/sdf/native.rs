//! The handle of a tape's native code: its entry point and the executable buffer that holds
//! it. [`crate::sdf::jit`] makes it, [`crate::sdf::tape::Tape`] carries it and
//! [`crate::sdf::simd::eval8`] runs it; it imports none of them, so the tape does not depend
//! on the compiler.

use std::sync::Arc;

/// Spill slots the code reads and writes: one per tape register.
pub const SLOTS: usize = 256;

/// The compiled function: `(x, y, z, scratch, out)`, see [`Native::eval8`].
#[cfg(target_arch = "x86_64")]
pub type Entry = unsafe extern "sysv64" fn(*const f32, *const f32, *const f32, *mut u8, *mut f32);

/// A tape's native code: an entry point into an executable buffer shared by the tapes
/// compiled together.
#[derive(Clone)]
pub struct Native {
    /// The buffer `entry` points into, kept alive while the tape can call it.
    #[cfg(target_arch = "x86_64")]
    code: Arc<dynasmrt::ExecutableBuffer>,
    #[cfg(target_arch = "x86_64")]
    entry: Entry,
    /// Bytes of this tape's own code in the buffer.
    #[cfg(target_arch = "x86_64")]
    len: usize,
    #[cfg(not(target_arch = "x86_64"))]
    _never: std::convert::Infallible,
}

impl std::fmt::Debug for Native {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Native")
    }
}

/// Native code is a cache of the tape's program: two tapes are equal when their programs are.
impl PartialEq for Native {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl Native {
    /// The handle of the function at `entry` in `code`, `len` bytes long.
    ///
    /// # Safety
    /// `entry` must point into `code` at a function with the [`Entry`] signature that reads 8
    /// floats at each of its first three arguments, at most [`SLOTS`] slots of 8 floats at the
    /// fourth and writes 8 floats at the fifth, using only instructions this CPU runs.
    #[cfg(target_arch = "x86_64")]
    pub unsafe fn new(code: Arc<dynasmrt::ExecutableBuffer>, entry: Entry, len: usize) -> Self {
        Native { code, entry, len }
    }

    /// The address of the executable buffer holding the code, shared by the tapes compiled
    /// together (of one object or many).
    pub fn buffer_address(&self) -> usize {
        #[cfg(target_arch = "x86_64")]
        {
            Arc::as_ptr(&self.code) as usize
        }
        #[cfg(not(target_arch = "x86_64"))]
        match self._never {}
    }

    /// Bytes of this tape's code (the buffer it shares with other tapes is larger).
    pub fn code_len(&self) -> usize {
        #[cfg(target_arch = "x86_64")]
        {
            self.len
        }
        #[cfg(not(target_arch = "x86_64"))]
        match self._never {}
    }

    /// The tape at 8 points: lane i is what the interpreter gives at (x[i], y[i], z[i]), bit
    /// for bit. `scratch` holds the spilled registers, at least [`SLOTS`] of them.
    #[inline]
    pub fn eval8(
        &self,
        x: &[f32; 8],
        y: &[f32; 8],
        z: &[f32; 8],
        scratch: &mut [[f32; 8]],
    ) -> [f32; 8] {
        assert!(scratch.len() >= SLOTS);
        #[cfg(target_arch = "x86_64")]
        {
            let mut out = [0.0f32; 8];
            // SAFETY: `Native::new`'s contract: the function reads 8 floats at each of `x`, `y`
            // and `z`, at most SLOTS slots of `scratch` (checked above) and writes 8 floats at
            // `out`; the buffer it lives in is held by `self`.
            unsafe {
                (self.entry)(
                    x.as_ptr(),
                    y.as_ptr(),
                    z.as_ptr(),
                    scratch.as_mut_ptr().cast(),
                    out.as_mut_ptr(),
                )
            };
            out
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = (x, y, z);
            match self._never {}
        }
    }
}
