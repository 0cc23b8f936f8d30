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
//! a few hold liquid, so these arrays ask for normal pages. Where the OS
//! does not allocate lazily the arrays are simply dense; results never
//! depend on it.

use crate::real::Real;

/// Arrays smaller than this are not worth an advice call.
const ADVISE_FROM_BYTES: usize = 8 << 20;

/// A vector of `len` zeros whose pages are backed only once written
/// (see the module's comment).
pub fn sparse_zeroed<T: Real>(len: usize) -> Vec<T> {
    // `vec![0.0; n]` of a float allocates zeroed memory (calloc), which for
    // large sizes is a fresh mapping: nothing is written here.
    let v = vec![T::ZERO; len];
    no_huge_pages(v.as_ptr() as *const u8, len * std::mem::size_of::<T>());
    v
}

/// Asks for normal pages under `len` bytes from `ptr` (untouched pages only).
fn no_huge_pages(ptr: *const u8, len: usize) {
    if len < ADVISE_FROM_BYTES {
        return;
    }
    #[cfg(target_os = "linux")]
    {
        const PAGE: usize = 4096;
        let start = (ptr as usize).next_multiple_of(PAGE);
        let end = (ptr as usize + len) / PAGE * PAGE;
        if end > start {
            // SAFETY: the range lies inside one live allocation; MADV_NOHUGEPAGE
            // changes how its pages are backed, never their contents. A
            // failure (a kernel without THP) leaves the default.
            unsafe { libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_NOHUGEPAGE) };
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = ptr;
}

/// How many of the pages under `bytes` from `ptr` are resident (Linux;
/// `None` elsewhere or on error).
pub fn resident_pages(ptr: *const u8, bytes: usize) -> Option<usize> {
    #[cfg(target_os = "linux")]
    {
        const PAGE: usize = 4096;
        let start = ptr as usize / PAGE * PAGE;
        let pages = (ptr as usize + bytes).div_ceil(PAGE) - start / PAGE;
        let mut map = vec![0u8; pages];
        // SAFETY: the range covers whole pages of one live allocation (the
        // first and last possibly shared with its neighbours, which mincore
        // only reads); `map` has one byte per page.
        let rc = unsafe { libc::mincore(start as *mut libc::c_void, pages * PAGE, map.as_mut_ptr()) };
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
        // One value every 16 MiB: 16 pages written.
        for k in (0..n).step_by(4 << 20) {
            v[k] = 1.0;
        }
        if let Some(pages) = resident_pages(v.as_ptr() as *const u8, n * 4) {
            // 16 pages and the allocator's header page at most. (Checked
            // before any read: a read maps the shared zero page, which
            // mincore counts, though it costs no memory.)
            assert!((16..=17).contains(&pages), "{pages} pages resident");
        }
        assert_eq!(v.iter().filter(|&&x| x == 1.0).count(), 16);
        assert_eq!(v.iter().filter(|&&x| x == 0.0).count(), n - 16);
    }
}
