//! Lattice arrays on 2 MiB pages.
//!
//! The lab column's lattice is 19.4M cells, of which ~0.6M hold liquid:
//! each active row is a short run of cells, and population i of a row lies
//! 78 MB from population i + 1. With 4 KiB pages every row the kernel
//! visits touches ~60 pages (19 populations read from up to nine rows and
//! written to one), each a TLB miss. Linux backs memory with transparent
//! huge pages only where asked (`/sys/kernel/mm/transparent_hugepage/enabled`
//! = `madvise`, the usual default), so the big arrays ask, before their
//! pages are first touched. Where huge pages are off or unknown (another OS)
//! this is a no-op; results never depend on it.

/// Arrays smaller than this stay on normal pages (less than one huge page
/// would be gained).
const HUGE_FROM_BYTES: usize = 8 << 20;

const HUGE_PAGE: usize = 2 << 20;

/// Asks for huge pages under the 2 MiB-aligned part of `len` bytes from
/// `ptr`. Only pages not yet touched are affected.
fn advise(ptr: *const u8, len: usize) {
    if len < HUGE_FROM_BYTES {
        return;
    }
    #[cfg(target_os = "linux")]
    {
        let start = (ptr as usize).next_multiple_of(HUGE_PAGE);
        let end = (ptr as usize + len) / HUGE_PAGE * HUGE_PAGE;
        if end > start {
            // SAFETY: the range lies inside one live allocation; MADV_HUGEPAGE
            // changes how its pages are backed, never their contents. A
            // failure (a kernel without THP) leaves normal pages.
            unsafe { libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_HUGEPAGE) };
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = ptr;
}

/// A vector of `len` elements `value(k)`, on huge pages where the OS gives
/// them. Filled on every thread of the pool: first touching ~3 GB of pages
/// (the lab column's lattice) is most of the lattice's set-up.
pub fn huge_vec<T: Send>(len: usize, value: impl Fn(usize) -> T + Sync + Send) -> Vec<T> {
    use rayon::prelude::*;
    let mut v = Vec::with_capacity(len);
    advise(v.as_ptr() as *const u8, len * std::mem::size_of::<T>());
    v.par_extend((0..len).into_par_iter().with_min_len(1 << 16).map(value));
    v
}

/// `values.len()` blocks of `block` elements, block i all `values[i]`, on
/// huge pages where the OS gives them (the populations: one block per
/// lattice direction), filled on every thread of the pool.
pub fn huge_blocks<T: Copy + Default + Send + Sync>(values: &[T], block: usize) -> Vec<T> {
    use rayon::prelude::*;
    // Filled per block: an index-to-block division per element took most
    // of the lattice's set-up.
    let mut v = huge_vec(values.len() * block, |_| T::default());
    v.par_chunks_mut(block.max(1)).zip(values).for_each(|(b, &x)| b.fill(x));
    v
}

/// A copy of `src` on huge pages where the OS gives them, made on every
/// thread of the pool.
pub fn huge_copy<T: Copy + Send + Sync>(src: &[T]) -> Vec<T> {
    use rayon::prelude::*;
    let mut v = Vec::with_capacity(src.len());
    advise(v.as_ptr() as *const u8, std::mem::size_of_val(src));
    v.par_extend(src.par_iter().with_min_len(1 << 16).copied());
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huge_vectors_hold_what_was_asked() {
        let n = (HUGE_FROM_BYTES / 4) * 3 + 7;
        let v = huge_vec(n, |k| k as u32);
        assert_eq!(v.len(), n);
        assert!(v.iter().enumerate().all(|(k, &x)| x == k as u32));
        assert_eq!(huge_copy(&v), v);
        assert_eq!(huge_copy(&[1.5f32, 2.5]), vec![1.5, 2.5]);
        let b = huge_blocks(&[1.0f32, 2.0, 3.0], n);
        assert_eq!(b.len(), 3 * n);
        assert!(b.iter().enumerate().all(|(k, &x)| x == (k / n + 1) as f32));
    }
}
