//! Lattice arrays whose memory follows the liquid.
//!
//! The lab column's box is 19.4 M cells, of which ~0.6 M hold liquid. Its
//! arrays are allocated zeroed and large, which the allocator serves with
//! fresh anonymous pages of the operating system: a page costs memory only
//! once it is first written, and reads of a page never written see zeros
//! without backing it. The lattice writes only where there is liquid (or
//! was), so its resident memory is that of the liquid's pages
//! (`fluid/layout.rs`). Transparent huge pages would back 2 MiB at the
//! first write into a region, a page of hundreds of segments of which only
//! a few hold liquid, so these arrays ask for normal pages. Pages of zeros
//! the liquid has left are given back ([`release_zeros`]). Where the OS
//! does not allocate lazily the arrays are simply dense; results never
//! depend on it.

use crate::real::Real;

/// Arrays smaller than this are not worth an advice call.
const ADVISE_FROM_BYTES: usize = 8 << 20;

/// The operating system's page size, bytes (4096 where it cannot be
/// read). Every range given back must be whole pages of this size: a
/// kernel rounds a release's length up to its own page, which would clear
/// values past the range.
pub fn page_size() -> usize {
    static PAGE: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *PAGE.get_or_init(|| {
        #[cfg(unix)]
        {
            // SAFETY: sysconf only reads a system constant.
            let size = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
            if size > 0 {
                return size as usize;
            }
        }
        4096
    })
}

/// A vector of `len` zeros whose pages are backed only once written
/// (see the module's comment).
pub fn sparse_zeroed<T: Real>(len: usize) -> Vec<T> {
    // `vec![0.0; n]` of a float allocates zeroed memory (calloc), which for
    // large sizes is a fresh mapping: nothing is written here.
    let v = vec![T::ZERO; len];
    no_huge_pages(v.as_ptr() as *const u8, len * std::mem::size_of::<T>());
    v
}

/// `len` zero bytes whose pages are backed only once written: the flags,
/// whose gas is 0 (`fluid::flags`).
pub fn sparse_zeroed_bytes(len: usize) -> Vec<u8> {
    let v = vec![0u8; len];
    no_huge_pages(v.as_ptr(), len);
    v
}

/// Asks for normal pages under `len` bytes from `ptr` (untouched pages only).
fn no_huge_pages(ptr: *const u8, len: usize) {
    if len < ADVISE_FROM_BYTES {
        return;
    }
    // SAFETY: the range lies inside one live allocation; MADV_NOHUGEPAGE
    // changes how its pages are backed, never their contents. A failure (a
    // kernel without THP) leaves the default.
    #[cfg(target_os = "linux")]
    unsafe {
        advise_whole_pages(ptr as usize, len, libc::MADV_NOHUGEPAGE)
    };
    #[cfg(not(target_os = "linux"))]
    let _ = ptr;
}

/// Gives `advice` for the whole pages inside `len` bytes from `ptr`: the
/// range rounded inward to the operating system's pages, since a kernel
/// rounds a length up to its own page and would reach past the range.
///
/// # Safety
/// The range lies inside one live allocation of the allocator (anonymous
/// memory), and `advice` changes no value the caller can read there:
/// MADV_DONTNEED only over zeros, which it makes read as zeros again.
#[cfg(target_os = "linux")]
unsafe fn advise_whole_pages(ptr: usize, len: usize, advice: libc::c_int) {
    let page = page_size();
    let start = ptr.next_multiple_of(page);
    let end = (ptr + len) / page * page;
    if end > start {
        // SAFETY: whole pages inside the caller's range (see above).
        unsafe { libc::madvise(start as *mut libc::c_void, end - start, advice) };
    }
}

/// Gives back to the operating system the whole pages inside
/// `values[range]`, which read as zeros afterwards (and cost no memory
/// until written again).
///
/// Pre: every element of `values[range]` is zero (all bits clear), so no
/// value changes (checked in debug builds), and `values` is memory of the
/// allocator (anonymous, as a `Vec`'s is: a file mapping's pages would
/// revert to the file). Elsewhere than Linux: nothing.
pub fn release_zeros<T: Real>(values: &mut [T], range: std::ops::Range<usize>) {
    let values = &mut values[range];
    debug_assert!(values.iter().all(|v| v.to_f64().to_bits() == 0), "release_zeros over non-zero values");
    // SAFETY: a mutably borrowed slice of a `Vec` (the precondition above),
    // all zero.
    unsafe { release_zeroed_range(values.as_mut_ptr() as usize, std::mem::size_of_val(values)) };
}

/// Gives back the whole pages of `values` that hold only zero bytes: the
/// flags of cells that are gas again, e.g. where a gate stood
/// (`fluid::flags`). Changes no value. Elsewhere than Linux: nothing.
pub fn release_zero_pages(values: &mut [u8]) {
    let page = page_size();
    let ptr = values.as_ptr() as usize;
    let first = ptr.next_multiple_of(page) - ptr;
    let mut run: Option<usize> = None;
    let mut at = first;
    let release = |values: &mut [u8]| {
        debug_assert!(values.iter().all(|&b| b == 0), "release over non-zero bytes");
        // SAFETY: a mutably borrowed slice of the caller's `Vec`, checked
        // zero page by page below.
        unsafe { release_zeroed_range(values.as_mut_ptr() as usize, values.len()) };
    };
    while at + page <= values.len() {
        let zero = values[at..at + page].iter().all(|&b| b == 0);
        match (zero, run) {
            (true, None) => run = Some(at),
            (false, Some(start)) => {
                release(&mut values[start..at]);
                run = None;
            }
            _ => {}
        }
        at += page;
    }
    if let Some(start) = run {
        release(&mut values[start..at]);
    }
}

/// MADV_DONTNEED over the whole pages of `len` bytes from `ptr`.
/// Elsewhere than Linux: nothing.
///
/// # Safety
/// The range is a slice the caller borrows mutably, of allocator memory
/// (private anonymous, as a `Vec`'s), holding only zeros: MADV_DONTNEED
/// makes its pages read as zeros, which they hold already.
unsafe fn release_zeroed_range(ptr: usize, len: usize) {
    // SAFETY: the caller's contract above.
    #[cfg(target_os = "linux")]
    unsafe {
        advise_whole_pages(ptr, len, libc::MADV_DONTNEED)
    };
    #[cfg(not(target_os = "linux"))]
    let _ = (ptr, len);
}

/// How many of the pages under `bytes` from `ptr` are resident (Linux;
/// `None` elsewhere or on error).
pub fn resident_pages(ptr: *const u8, bytes: usize) -> Option<usize> {
    #[cfg(target_os = "linux")]
    {
        let page = page_size();
        let start = ptr as usize / page * page;
        let pages = (ptr as usize + bytes).div_ceil(page) - start / page;
        let mut map = vec![0u8; pages];
        // SAFETY: the range covers whole pages of one live allocation (the
        // first and last possibly shared with its neighbours, which mincore
        // only reads); `map` has one byte per page.
        let rc = unsafe { libc::mincore(start as *mut libc::c_void, pages * page, map.as_mut_ptr()) };
        (rc == 0).then(|| map.iter().filter(|&&b| b & 1 == 1).count())
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (ptr, bytes);
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sparse_vectors_are_zero_and_cost_only_the_pages_written() {
        let n = 64 << 20; // 256 MiB of f32
        let mut v: Vec<f32> = sparse_zeroed(n);
        assert_eq!(v.len(), n);
        // One value every 16 MiB from 4 MiB on: 16 pages written. (The
        // first 4 MiB are left out: where huge pages are always on, the
        // allocator's header write may back a 2 MiB page there before the
        // advice.)
        let skip = 1 << 20;
        for k in (skip..n).step_by(4 << 20) {
            v[k] = 1.0;
        }
        if let Some(pages) = resident_pages(v[skip..].as_ptr() as *const u8, (n - skip) * 4) {
            // Checked before any read: a read maps the shared zero page,
            // which mincore counts, though it costs no memory.
            assert_eq!(pages, 16, "pages resident");
        }
        assert_eq!(v.iter().filter(|&&x| x == 1.0).count(), 16);
        release_zeros(&mut v, 0..skip);
        assert_eq!(v.iter().filter(|&&x| x == 0.0).count(), n - 16);
    }
}
