//! Read-only arrays in memory that the kernel may back with 2 MB pages (the trees' nodes and
//! leaf blocks).
//!
//! **Why.** A walk touches its tree at random, and a tree is megabytes (the bench's models: 4
//! to 75 MB of nodes and leaf blocks), more than a core's second-level TLB covers with 4 KB
//! pages (8 MB on AMD Zen 3, less on many Intel cores); with 2 MB pages it covers gigabytes.
//! Linux backs an anonymous mapping with 2 MB pages only where it was asked to
//! (`MADV_HUGEPAGE`) when transparent huge pages are in their `madvise` mode, the default of
//! many distributions (Debian's included), and the standard allocator never asks. Embree asks
//! for every allocation of its trees (`os_malloc` in its `common/sys/alloc.cpp`), so the bench
//! compared its trees in huge pages with ours in small ones. Measured on the bench's rays
//! (BENCHMARKS.md, "Trees in huge pages"): primary and AO rays 1–4 % faster on the bunny, the
//! saw and the engine, the other ray kinds within 1 %, and no change on the million-triangle
//! model, whose walks wait on memory itself more than on page-table walks.
//!
//! **How.** An array of at least one huge page is written into a fresh anonymous mapping
//! (`memmap2`) whose whole huge pages under the array are advised for huge pages before the
//! first write, so that they are faulted in as huge pages; a smaller array, or one on a system
//! without the advice, stays a `Vec`. The mapping starts out zeroed, a valid value of any
//! [`Pod`] type, so it is filled as a slice of `T` without unsafe code; only the read path keeps
//! a raw pointer, so that an index costs what a `Vec`'s does (these arrays are indexed in the
//! innermost loops of every walk).

use std::fmt;
use std::ops::Deref;
use std::ptr::NonNull;

use bytemuck::Pod;

/// Bytes of one huge page (x86-64 and AArch64 with 4 KB base pages): arrays smaller than
/// this gain nothing from a mapping of their own.
const HUGE_PAGE: usize = 2 << 20;

/// An immutable array of `T`, in memory advised for transparent huge pages when it is at
/// least one huge page large (see the module notes). Dereferences to `[T]`.
pub(crate) struct HugePageArray<T: Pod> {
    /// The first element (dangling when empty); valid for `len` reads while `_owner` lives.
    ptr: NonNull<T>,
    len: usize,
    _owner: Owner<T>,
}

/// What holds the elements. Neither moves its buffer when moved itself.
enum Owner<T> {
    Vec(#[allow(dead_code)] Vec<T>),
    #[cfg(target_os = "linux")]
    Map(#[allow(dead_code)] memmap2::MmapMut),
}

// SAFETY: the array owns its elements (a `Vec` or a private mapping) and hands out only shared
// references to them, like a `Box<[T]>`.
unsafe impl<T: Pod + Send> Send for HugePageArray<T> {}
// SAFETY: as above; there is no interior mutability.
unsafe impl<T: Pod + Sync> Sync for HugePageArray<T> {}

impl<T: Pod> HugePageArray<T> {
    /// An array of `len` elements, written by `fill` (which receives them zeroed).
    pub fn new_with(len: usize, fill: impl FnOnce(&mut [T])) -> Self {
        #[cfg(target_os = "linux")]
        if let Some(map) = Self::huge_mapping(len) {
            return Self::in_map(map, len, fill);
        }
        let mut v = vec![T::zeroed(); len];
        fill(&mut v);
        Self::in_vec(v)
    }

    /// The elements of `items`, copied into huge pages when they fill one.
    pub fn from_vec(items: Vec<T>) -> Self {
        #[cfg(target_os = "linux")]
        if let Some(map) = Self::huge_mapping(items.len()) {
            return Self::in_map(map, items.len(), |out| out.copy_from_slice(&items));
        }
        Self::in_vec(items)
    }

    fn in_vec(mut items: Vec<T>) -> Self {
        HugePageArray {
            // (A `Vec`'s pointer is never null; an empty one's is dangling, as it may be.)
            ptr: NonNull::new(items.as_mut_ptr()).unwrap_or(NonNull::dangling()),
            len: items.len(),
            _owner: Owner::Vec(items),
        }
    }

    /// The array in `map` from byte `start` (see [`Self::huge_mapping`]), written by `fill`.
    #[cfg(target_os = "linux")]
    fn in_map(
        (mut map, start): (memmap2::MmapMut, usize),
        len: usize,
        fill: impl FnOnce(&mut [T]),
    ) -> Self {
        let bytes = &mut map[start..start + len * size_of::<T>()];
        let elements: &mut [T] = bytemuck::cast_slice_mut(bytes);
        fill(elements);
        HugePageArray {
            ptr: NonNull::from(&mut elements[0]),
            len,
            _owner: Owner::Map(map),
        }
    }

    /// A zeroed anonymous mapping for `len` elements, and the byte where they start, with the
    /// whole huge pages they span advised for huge pages; or `None` when the array is smaller
    /// than one huge page or the system refuses the mapping or the advice (the caller then
    /// uses a `Vec`).
    ///
    /// The mapping is one huge page longer than the array, which starts at its first
    /// huge-page boundary: the slack before it is never written, so never backed. Only the
    /// array's whole huge pages are advised: a huge page is backed whole once any byte of it
    /// is written, so the array's last, partial one stays in 4 KB pages rather than cost up to
    /// 2 MB of memory that holds nothing.
    #[cfg(target_os = "linux")]
    fn huge_mapping(len: usize) -> Option<(memmap2::MmapMut, usize)> {
        let bytes = len.checked_mul(size_of::<T>())?;
        // (Alignments above a huge page would need a later start; no tree stores such a type.)
        if bytes < HUGE_PAGE || align_of::<T>() > HUGE_PAGE {
            return None;
        }
        let map = memmap2::MmapMut::map_anon(bytes.checked_add(HUGE_PAGE)?).ok()?;
        let start = (map.as_ptr() as usize).next_multiple_of(HUGE_PAGE) - map.as_ptr() as usize;
        let whole = bytes / HUGE_PAGE * HUGE_PAGE;
        map.advise_range(memmap2::Advice::HugePage, start, whole)
            .ok()?;
        Some((map, start))
    }
}

impl<T: Pod> Deref for HugePageArray<T> {
    type Target = [T];
    #[inline(always)]
    fn deref(&self) -> &[T] {
        // SAFETY: `ptr` points at `len` initialised elements owned by `_owner` (a `Vec`'s
        // buffer or a mapping, neither of which moves or changes while `self` lives).
        unsafe { std::slice::from_raw_parts(self.ptr.as_ptr(), self.len) }
    }
}

impl<T: Pod> Clone for HugePageArray<T> {
    fn clone(&self) -> Self {
        Self::new_with(self.len, |out| out.copy_from_slice(self))
    }
}

impl<T: Pod> Default for HugePageArray<T> {
    fn default() -> Self {
        Self::from_vec(Vec::new())
    }
}

impl<T: Pod + fmt::Debug> fmt::Debug for HugePageArray<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_and_large_arrays_hold_what_was_written() {
        for len in [0usize, 1, 1000, HUGE_PAGE / 4 + 3] {
            let v: Vec<u32> = (0..len as u32)
                .map(|i| i.wrapping_mul(2_654_435_761))
                .collect();
            let a = HugePageArray::from_vec(v.clone());
            assert_eq!(&a[..], &v[..]);
            let b = a.clone();
            drop(a);
            assert_eq!(&b[..], &v[..]);
            let c = HugePageArray::new_with(len, |out: &mut [u32]| {
                assert!(out.iter().all(|&x| x == 0), "handed out zeroed");
                out.copy_from_slice(&v);
            });
            assert_eq!(&c[..], &v[..]);
        }
    }

    /// The flags (`VmFlags` of `/proc/self/smaps`) of the mapping that holds `addr`.
    #[cfg(target_os = "linux")]
    fn vm_flags_at(addr: usize) -> Vec<String> {
        let smaps = std::fs::read_to_string("/proc/self/smaps").expect("smaps");
        let mut in_map = false;
        for line in smaps.lines() {
            let range = line.split_once(' ').and_then(|(r, _)| r.split_once('-'));
            if let Some((lo, hi)) = range
                && let (Ok(lo), Ok(hi)) =
                    (usize::from_str_radix(lo, 16), usize::from_str_radix(hi, 16))
            {
                in_map = (lo..hi).contains(&addr);
            } else if in_map && let Some(f) = line.strip_prefix("VmFlags:") {
                return f.split_whitespace().map(str::to_owned).collect();
            }
        }
        panic!("no mapping with flags holds {addr:#x}");
    }

    /// A large array's whole huge pages carry the advice (the `hg` flag), and its last, partial
    /// one does not: what this type exists for, without memory that holds nothing. Whether the
    /// kernel then grants huge pages depends on its settings and on free memory, so that is
    /// not asserted.
    #[cfg(target_os = "linux")]
    #[test]
    fn whole_huge_pages_of_large_arrays_are_advised() {
        let len = HUGE_PAGE / 4 * 3 / 2; // one and a half huge pages of u32
        let a = HugePageArray::new_with(len, |out: &mut [u32]| out.fill(7));
        assert!(matches!(a._owner, Owner::Map(_)), "a large array is mapped");
        assert_eq!(
            a.as_ptr() as usize % HUGE_PAGE,
            0,
            "it starts on a huge page"
        );
        let first = vm_flags_at(a.as_ptr() as usize);
        assert!(first.iter().any(|f| f == "hg"), "not advised: {first:?}");
        let last = vm_flags_at(&a[len - 1] as *const u32 as usize);
        assert!(
            !last.iter().any(|f| f == "hg"),
            "partial page advised: {last:?}"
        );
        assert!(a.iter().all(|&x| x == 7));
    }
}
